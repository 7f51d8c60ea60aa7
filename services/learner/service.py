"""Learner: ingests every collector's chunks into the replay (MCAP on disk) and trains.

Subscribes:  ursa/{run}/collector/transitions/* (TransitionChunk, BLOCK)
Publishes:   ursa/{run}/learner/stats (Stats)
Liveliness:  ursa/{run}/alive/learner/{id}
"""

from __future__ import annotations

import os
import queue
import time
from dataclasses import dataclass, field

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import safe_handler
from services.common.config import BusConfig, RunConfig, save_resolved
from services.common.runtime import ServiceRuntime
from services.learner.ingest import IngestLedger
from services.learner.replay_store import ReplayWriter, read_all
from ursa.config import Config


@dataclass(frozen=True)
class LearnerArgs:
    """Learner service settings."""

    core: Config = field(default_factory=Config)
    bus: BusConfig = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)
    learner_id: str = os.environ.get("URSA_LEARNER_ID", "main")
    """Id of this learner in its liveliness token."""
    stats_hz: float = 2.0
    """How often metrics are published."""
    segment_chunks: int = 2000
    """Chunks per MCAP replay segment before rotating to a new file."""


class LearnerService:
    """Learner process shell: messages in, core calls, messages out."""

    def __init__(self, args: LearnerArgs) -> None:
        self.args = args
        self.rt = ServiceRuntime("learner", args.learner_id, args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, "learner")
        self.ledger = IngestLedger()
        self.replay_dir = args.run.dir / "replay"
        self.restored_chunks = self._restore()
        self.writer = ReplayWriter(self.replay_dir, args.segment_chunks)
        self.inbox: queue.Queue[pb.TransitionChunk] = queue.Queue()
        self.sub = self.rt.session.declare_subscriber(
            self.rt.topics.transitions(),
            safe_handler(pb.TransitionChunk, self._on_chunk, self.rt.drops, args.run.run_id),
        )

    def _restore(self) -> int:
        n = 0
        for chunk in read_all(self.replay_dir):
            self._admit(chunk, write=False)
            n += 1
        if n:
            self.log.info("restored %d chunks (%d steps) from %s", n, self.ledger.total_steps,
                          self.replay_dir)
        return n

    def _on_chunk(self, msg: pb.TransitionChunk, key: str) -> None:
        # validate in the callback thread so a bad array is counted as a drop there
        obs = codec.from_array(msg.obs)
        if obs.ndim != 2 or obs.shape[0] == 0:
            raise codec.BadMessage(f"chunk obs of shape {obs.shape}")
        for name in ("action", "reward", "cost", "safe", "features", "skill"):
            a = codec.from_array(getattr(msg, name))
            if a.shape[:1] != obs.shape[:1]:
                raise codec.BadMessage(f"chunk {name} has {a.shape[:1]} rows, obs {obs.shape[0]}")
        self.inbox.put(msg)

    def _admit(self, chunk: pb.TransitionChunk, write: bool = True) -> bool:
        n = int(chunk.obs.shape[0])
        ok, _starts = self.ledger.admit(chunk.collector_id, int(chunk.incarnation), int(chunk.seq),
                                        int(chunk.first_step), n, int(chunk.policy_version))
        if ok and write:
            self.writer.write(chunk)
        return ok

    def run(self) -> None:
        period = 1.0 / self.args.stats_hz
        last = 0.0
        while not self.rt.stop.is_set():
            try:
                chunk = self.inbox.get(timeout=0.05)
                self._admit(chunk)
                while True:
                    self._admit(self.inbox.get_nowait())
            except queue.Empty:
                pass
            now = time.monotonic()
            if now - last >= period:
                self.publish_stats()
                last = now

    def publish_stats(self) -> None:
        scalars: dict[str, float] = {
            "replay_steps": self.ledger.total_steps,
            "collectors_seen": len(self.ledger.streams),
        }
        for cid, st in self.ledger.streams.items():
            scalars[f"chunks/{cid}"] = st.chunks
            scalars[f"gaps/{cid}"] = st.gaps
            scalars[f"missing/{cid}"] = st.missing_chunks
            scalars[f"duplicates/{cid}"] = st.duplicates
            scalars[f"next_seq/{cid}"] = st.next_seq
        self.rt.publish_stats(scalars)

    def close(self) -> None:
        try:
            self.sub.undeclare()
        except Exception:
            pass
        while not self.inbox.empty():
            self._admit(self.inbox.get_nowait())
        self.writer.close()
        self.rt.close()
