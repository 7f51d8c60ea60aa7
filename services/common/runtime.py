"""What every long-running service does the same way: session, presence, stats, shutdown."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import numpy as np
import zenoh

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.common.bus import DropCounter, open_session, publisher
from services.common.config import BusConfig, RunConfig
from services.common.metrics import MetricsLog


class ServiceRuntime:
    """A service's bus session, liveliness token, drop counter and stats publisher."""

    def __init__(self, service: str, sid: str, bus: BusConfig, run: RunConfig) -> None:
        self.service = service
        self.sid = sid
        self.run = run
        self.topics = Topics(run.run_id)
        self.sender = f"{service}/{sid}"
        self.log = logging.getLogger(self.sender)
        self.drops = DropCounter()
        self.session: zenoh.Session = open_session(bus, service, run)
        self._token = self.session.liveliness().declare_token(self.topics.alive(service, sid))
        key = self.topics.stats(service, sid)
        self._stats_pub = publisher(self.session, key, reliable=False)
        self.started = time.time()
        self.stop = threading.Event()
        self.metrics = MetricsLog(run.dir, run.run_id, service, sid, run.wandb)
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
        msg.scalars.update(self.drops.scalars())
        msg.labels.update(self.drops.labels())
        msg.scalars["uptime_s"] = time.time() - self.started
        for k, s in (labels or {}).items():
            msg.labels[k] = s
        for k, a in (arrays or {}).items():
            msg.arrays[k].CopyFrom(codec.to_array(np.asarray(a)))
        self._stats_pub.put(codec.encode(msg))
        self._record(msg)

    def _record(self, msg: pb.Stats, force: bool = False) -> None:
        """Write the stats to the run's metrics (JSONL, TensorBoard, W&B: the source of training
        curves), at most every ``run.metrics_every_s``."""
        now = time.time()
        if not force and now - self._metrics_last < self.run.metrics_every_s:
            return
        self._metrics_last = now
        self.metrics.write(now, dict(msg.scalars), dict(msg.labels))

    def close(self) -> None:
        self.metrics.close()
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
