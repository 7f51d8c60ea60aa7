"""The Zenoh session every URSA process uses, and small helpers around it.

Every process is a ``client`` of one router with multicast scouting off; the router itself is a
Python process in ``router`` mode (``python -m services.router``).

Trust (DESIGN §4): every payload is a frame checked by :mod:`proto.codec` before it is parsed
(a MAC under the run key when the run has one, see :mod:`services.common.secrets`); what fails
is counted per reason, per key and per claimed publisher in a :class:`DropCounter` and dropped.
With authentication on, a client presents its role's user/password to the router, whose access
rules say which role may publish what.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import zenoh
from google.protobuf.message import Message

from proto import codec
from services.common import secrets
from services.common.config import BusConfig, RunConfig
from ursa.bounds import OutOfBounds

if TYPE_CHECKING:
    from services.common.validate import Validator
    from ursa.config import Config

log = logging.getLogger(__name__)
M = TypeVar("M", bound=Message)


def client_config(bus: BusConfig, credentials: secrets.Credentials | None = None) -> zenoh.Config:
    """A client-mode config connected to ``bus.router`` with scouting off; with
    ``credentials``, the client authenticates with that user/password."""
    conf = zenoh.Config()
    if credentials is not None:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(credentials.user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(credentials.password))
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([bus.router]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # keep retrying the router forever once connected: a restarted router is rejoined
    conf.insert_json5("connect/timeout_ms", json.dumps(int(bus.connect_timeout_s * 1000)))
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def router_config(bus: BusConfig, auth: secrets.RouterAuth | None = None) -> zenoh.Config:
    """A router-mode config listening on ``bus.listen`` with scouting off; with ``auth``, clients
    must authenticate (user/password dictionary) and the run's access rules apply."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([bus.listen]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if auth is not None:
        conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(auth.dictionary)))
        conf.insert_json5("access_control", json.dumps(secrets.access_control(auth.run_id)))
    return conf


def open_session(
    bus: BusConfig, role: str | None = None, run: RunConfig | None = None
) -> zenoh.Session:
    """Open a client session, retrying until the router answers or the timeout passes.

    Sets the run key of :mod:`proto.codec` (``bus.key_file``, else ``<run>/secrets/bus.key``
    when it exists) and, when authentication is on (:func:`secrets.client_credentials`), logs in
    as ``role``.
    """
    zenoh.try_init_log_from_env()
    key = secrets.find_run_key(bus, run)
    if key is not None or codec.run_key() is None:
        codec.set_run_key(key)
    creds = secrets.client_credentials(bus, role, run)
    deadline = time.monotonic() + bus.connect_timeout_s
    while True:
        try:
            return zenoh.open(client_config(bus, creds))
        except zenoh.ZError as e:
            if time.monotonic() > deadline:
                who = f" as {creds.user!r}" if creds else " without credentials"
                raise ConnectionError(
                    f"no zenoh router at {bus.router} accepted this client{who}"
                    f" (is authentication on?): {e}"
                ) from e
            time.sleep(0.5)


class DropCounter:
    """Counts payloads that were received but rejected, by reason, by key and by the publisher
    they claim to come from; thread-safe. At most ``MAX_TRACKED`` distinct keys (and
    publishers) are kept apart; further ones are counted under ``"(other)"`` so that a flood of
    made-up keys cannot grow the counter without bound."""

    MAX_TRACKED = 64

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.by_key: Counter[str] = Counter()
        self.by_sender: Counter[str] = Counter()

    @classmethod
    def _bump(cls, c: Counter[str], name: str) -> None:
        if name not in c and len(c) >= cls.MAX_TRACKED:
            name = "(other)"
        c[name] += 1

    def add(self, reason: str, key: str = "", sender: str = "") -> None:
        with self._lock:
            self.counts[reason] += 1
            if key:
                self._bump(self.by_key, key)
            if sender:
                self._bump(self.by_sender, sender)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self.counts.values())

    def scalars(self) -> dict[str, float]:
        """``dropped/<reason>`` counts, for a service's Stats."""
        with self._lock:
            return {f"dropped/{r}": float(n) for r, n in self.counts.items()}

    def labels(self) -> dict[str, str]:
        """Drops per key and per claimed publisher as JSON objects, for a service's Stats."""
        with self._lock:
            return {
                "dropped_by_key": json.dumps(dict(self.by_key), sort_keys=True),
                "dropped_by_sender": json.dumps(dict(self.by_sender), sort_keys=True),
            }


class Rejected(codec.BadMessage):
    """A message that decodes but fails its semantic check (values outside what its producer
    declares, or an impossible origin): a ``BadMessage`` so that every receiver drops it."""


_validator_lock = threading.Lock()
_validator: Validator | None = None


def validate_with(cfg: Config | None) -> Validator:
    """Check every message this process decodes through :func:`checked_decode` (hence every
    :func:`safe_handler` and :func:`query_one`) against the bounds of ``cfg``; returns the
    validator. Until a service calls it, only the checks needing no config run."""
    from services.common.validate import Validator

    global _validator
    with _validator_lock:
        _validator = Validator(cfg)
        return _validator


def validator() -> Validator:
    global _validator
    with _validator_lock:
        if _validator is None:
            from services.common.validate import Validator

            _validator = Validator(None)
        return _validator


def checked_decode(
    cls: type[M], payload: bytes | bytearray | memoryview, run_id: str | None = None, key: str = ""
) -> M:
    """``codec.decode`` and then the semantic check of the message (received on ``key``);
    raises ``codec.BadMessage`` (``Rejected`` for a failed semantic check)."""
    msg = codec.decode(cls, payload, run_id=run_id)
    try:
        validator()(msg, key)
    except (OutOfBounds, codec.BadMessage) as e:
        raise Rejected(str(e)) from e
    return msg


def reason_of(e: Exception) -> str:
    """The drop reason of a rejected payload: ``integrity`` (frame, checksum or MAC),
    ``out_of_bounds`` (values outside what the producer declares) or ``malformed``."""
    if isinstance(e, codec.IntegrityError):
        return "integrity"
    if isinstance(e, (OutOfBounds, Rejected)):
        return "out_of_bounds"
    return "malformed"


def safe_handler(
    cls: type[M],
    fn: Callable[[M, str], None],
    drops: DropCounter,
    run_id: str | None = None,
    name: str = "",
) -> Callable[[zenoh.Sample], None]:
    """Wrap ``fn(msg, key)`` as a subscriber callback that decodes ``cls``.

    Payloads that fail their integrity check, are malformed, oversized or of another version
    are counted in ``drops`` (by reason, key and claimed publisher) and logged; ``fn`` raising
    ``BadMessage`` (e.g. values out of bounds) counts the same way; any other exception in
    ``fn`` is logged and counted too: a callback never takes the service down.
    """

    def handler(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        try:
            msg = checked_decode(cls, payload, run_id=run_id, key=key)
        except codec.BadMessage as e:
            drops.add(reason_of(e), key, codec.claimed_sender(payload))
            log.warning("dropped %s on %s: %s", cls.__name__, key, e)
            return
        sender = msg.header.sender  # type: ignore[attr-defined]
        try:
            fn(msg, key)
        except (codec.BadMessage, OutOfBounds) as e:
            drops.add("out_of_bounds" if isinstance(e, OutOfBounds) else "invalid", key, sender)
            log.warning("dropped %s on %s: %s", cls.__name__, key, e)
        except Exception:
            drops.add("handler_error", key, sender)
            log.exception("handler %s failed on %s", name or cls.__name__, key)

    return handler


def query_one(
    session: zenoh.Session,
    key: str,
    cls: type[M],
    payload: bytes | None = None,
    timeout_s: float = 2.0,
    drops: DropCounter | None = None,
    check: Callable[[M], object] | None = None,
) -> M | None:
    """Send a query and return the first valid reply decoded as ``cls`` (and passing
    ``check``, which raises ``BadMessage`` to refuse it), or None; bad replies are counted in
    ``drops`` when given."""
    try:
        replies = session.get(key, payload=payload, timeout=timeout_s)
        for reply in replies:
            if reply.ok is None:
                continue
            data = reply.ok.payload.to_bytes()
            try:
                msg = checked_decode(cls, data, key=key)
                if check is not None:
                    check(msg)
                return msg
            except (codec.BadMessage, OutOfBounds) as e:
                if drops is not None:
                    drops.add(reason_of(e), key, codec.claimed_sender(data))
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
