"""What every long-running service does the same way: session, presence, stats, shutdown."""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import IO, Any

import numpy as np
import zenoh

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.common.bus import DropCounter, open_session, publisher
from services.common.config import BusConfig, RunConfig


class ServiceRuntime:
    """A service's bus session, liveliness token, drop counter and stats publisher."""

    METRICS_EVERY_S = 5.0
    """Stats are also appended to ``<run>/metrics/<service>-<id>.jsonl`` at most this often."""

    def __init__(self, service: str, sid: str, bus: BusConfig, run: RunConfig) -> None:
        self.service = service
        self.sid = sid
        self.run = run
        self.topics = Topics(run.run_id)
        self.sender = f"{service}/{sid}"
        self.log = logging.getLogger(self.sender)
        self.drops = DropCounter()
        self.session: zenoh.Session = open_session(bus)
        self._token = self.session.liveliness().declare_token(self.topics.alive(service, sid))
        key = self.topics.stats(service, sid)
        self._stats_pub = publisher(self.session, key, reliable=False)
        self.started = time.time()
        self.stop = threading.Event()
        self._metrics_file: IO[str] | None = None
        self._metrics_last = 0.0

    def header(self) -> pb.Header:
        return codec.header(self.run.run_id, self.sender)

    def publish_stats(
        self,
        scalars: dict[str, float],
        labels: dict[str, str] | None = None,
        arrays: dict[str, np.ndarray] | None = None,
    ) -> None:
        """Publish a ``Stats`` message (latest-value stream: may drop under congestion)."""
        msg = pb.Stats(header=self.header(), service=self.service, id=self.sid)
        for k, v in scalars.items():
            msg.scalars[k] = float(v)
        msg.scalars["dropped_messages"] = float(self.drops.total)
        msg.scalars["uptime_s"] = time.time() - self.started
        for k, s in (labels or {}).items():
            msg.labels[k] = s
        for k, a in (arrays or {}).items():
            msg.arrays[k].CopyFrom(codec.to_array(np.asarray(a)))
        self._stats_pub.put(codec.encode(msg))
        self._record(msg)

    def _record(self, msg: pb.Stats, force: bool = False) -> None:
        """Append the stats to the run's metrics file (the source of training curves)."""
        now = time.time()
        if not force and now - self._metrics_last < self.METRICS_EVERY_S:
            return
        self._metrics_last = now
        if self._metrics_file is None:
            path = self.run.dir / "metrics" / f"{self.service}-{self.sid}.jsonl"
            path.parent.mkdir(parents=True, exist_ok=True)
            self._metrics_file = open(path, "a")  # noqa: SIM115 - open for the service's life
        row = {"t": now, "service": self.service, "id": self.sid,
               "scalars": dict(msg.scalars), "labels": dict(msg.labels)}
        self._metrics_file.write(json.dumps(row) + "\n")
        self._metrics_file.flush()

    def close(self) -> None:
        if self._metrics_file is not None:
            self._metrics_file.close()
        for obj in (self._token, self._stats_pub):
            try:
                obj.undeclare()
            except Exception:  # already gone with a dead router: nothing to release
                pass
        self.session.close()

    def __enter__(self) -> ServiceRuntime:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
