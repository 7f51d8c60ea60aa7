"""The Zenoh session every URSA process uses, and small helpers around it.

Every process is a ``client`` of one router with multicast scouting off; the router itself is a
Python process in ``router`` mode (``python -m services.router``).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, TypeVar

import zenoh
from google.protobuf.message import Message

from proto import codec
from services.common.config import BusConfig

log = logging.getLogger(__name__)
M = TypeVar("M", bound=Message)


def client_config(bus: BusConfig) -> zenoh.Config:
    """A client-mode config connected to ``bus.router`` with scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([bus.router]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # keep retrying the router forever once connected: a restarted router is rejoined
    conf.insert_json5("connect/timeout_ms", json.dumps(int(bus.connect_timeout_s * 1000)))
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def router_config(bus: BusConfig) -> zenoh.Config:
    """A router-mode config listening on ``bus.listen`` with scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([bus.listen]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def open_session(bus: BusConfig) -> zenoh.Session:
    """Open a client session, retrying until the router answers or the timeout passes."""
    zenoh.try_init_log_from_env()
    deadline = time.monotonic() + bus.connect_timeout_s
    while True:
        try:
            return zenoh.open(client_config(bus))
        except zenoh.ZError as e:
            if time.monotonic() > deadline:
                raise ConnectionError(f"no zenoh router at {bus.router}: {e}") from e
            time.sleep(0.5)


class DropCounter:
    """Counts payloads that were received but rejected, by reason; thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: Counter[str] = Counter()

    def add(self, reason: str) -> None:
        with self._lock:
            self.counts[reason] += 1

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self.counts.values())


def safe_handler(
    cls: type[M],
    fn: Callable[[M, str], None],
    drops: DropCounter,
    run_id: str | None = None,
    name: str = "",
) -> Callable[[zenoh.Sample], None]:
    """Wrap ``fn(msg, key)`` as a subscriber callback that decodes ``cls``.

    Malformed, oversized or wrong-version payloads are counted in ``drops`` and logged; an
    exception in ``fn`` is logged and counted too: a callback never takes the service down.
    """

    def handler(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            msg = codec.decode(cls, sample.payload.to_bytes(), run_id=run_id)
        except codec.BadMessage as e:
            drops.add("malformed")
            log.warning("dropped %s on %s: %s", cls.__name__, key, e)
            return
        try:
            fn(msg, key)
        except codec.BadMessage as e:
            drops.add("invalid")
            log.warning("dropped %s on %s: %s", cls.__name__, key, e)
        except Exception:
            drops.add("handler_error")
            log.exception("handler %s failed on %s", name or cls.__name__, key)

    return handler


def query_one(
    session: zenoh.Session,
    key: str,
    cls: type[M],
    payload: bytes | None = None,
    timeout_s: float = 2.0,
) -> M | None:
    """Send a query and return the first valid reply decoded as ``cls``, or None."""
    try:
        replies = session.get(key, payload=payload, timeout=timeout_s)
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return codec.decode(cls, reply.ok.payload.to_bytes())
            except codec.BadMessage as e:
                log.warning("bad reply on %s: %s", key, e)
    except zenoh.ZError as e:
        log.warning("query %s failed: %s", key, e)
    return None


class Presence:
    """Tracks live tokens under a key expression (liveliness subscriber with history)."""

    def __init__(self, session: zenoh.Session, key_expr: str) -> None:
        self._lock = threading.Lock()
        self._alive: dict[str, float] = {}
        self._sub = session.liveliness().declare_subscriber(key_expr, self._on, history=True)

    def _on(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.setdefault(key, time.time())
            else:
                self._alive.pop(key, None)

    def alive(self) -> dict[str, float]:
        """Live keys with the time each was first seen."""
        with self._lock:
            return dict(self._alive)

    def undeclare(self) -> None:
        self._sub.undeclare()


def publisher(session: zenoh.Session, key: str, reliable: bool) -> Any:
    """A publisher: ``reliable`` streams block under congestion, others may drop."""
    cc = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
    return session.declare_publisher(key, congestion_control=cc)
