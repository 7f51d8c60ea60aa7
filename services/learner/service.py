"""Learner: ingests every collector's chunks into the replay (MCAP on disk) and trains the world
model, critics, multipliers, actor (and VAE) continuously (paper Algorithm 2).

Subscribes:  ursa/{run}/collector/transitions/* (TransitionChunk, BLOCK)
             ursa/{run}/repertoire/snapshot (RepertoireSnapshot; also queried at start)
Queryables:  ursa/{run}/learner/weights (-> PolicyWeights, the latest)
             ursa/{run}/learner/encoder (-> EncoderWeights, the latest; learned phi only)
Publishes:   ursa/{run}/learner/weights (PolicyWeights, every few seconds)
             ursa/{run}/learner/encoder (EncoderWeights, on each new version)
             ursa/{run}/learner/stats (Stats: losses, λ1/λ2, replay, ratio, policy lag)
Liveliness:  ursa/{run}/alive/learner/{id}; watches ursa/{run}/alive/collector/*
Files:       <run>/replay/segment-*.mcap, <run>/checkpoints/learner.pt + learner_state.json
"""

from __future__ import annotations

import errno
import json
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh
from safetensors.torch import save as st_save

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.common.bus import Presence, publisher, query_one, safe_handler, validate_with
from services.common.config import (
    ServiceArgs,
    config_hash,
    env_field,
    save_resolved,
)
from services.common.runtime import ServiceRuntime
from services.learner.ingest import IngestLedger
from services.learner.replay_store import ReplayWriter, read_all
from ursa import bounds, kde
from ursa.config import build_env
from ursa.learner import Learner, SkillSnapshot
from ursa.networks import dtype_name
from ursa.pace import default_slack, insert_budget
from ursa.replay import Replay
from ursa.rundir import TEMP_SUFFIX, RunDir, atomic_write
from ursa.safety_floor import ema_rate
from ursa.threads import limit_threads

CHUNK_FIELDS = ("obs", "action", "reward", "cost", "safe", "features", "skill")
LATENCY_WINDOW_S = 60.0
"""The stats' chunk latency is over the chunks received in this many seconds: a window of the
last N chunks would, at a paced collector's ~1 chunk/s, hold the chunks a collector kept while
no learner listened (its start-up backlog, seconds old when sent) for the whole run."""


def latency_stats(latencies: Iterable[tuple[float, float]], now: float) -> dict[str, float]:
    """p50, p99 (ms) and count of the latencies (s) received after ``now − LATENCY_WINDOW_S``;
    ``latencies`` holds (receipt time, latency) pairs. Empty when none is that recent."""
    lat = [x for t, x in latencies if t >= now - LATENCY_WINDOW_S]
    if not lat:
        return {}
    ms = np.asarray(lat) * 1e3
    return {
        "chunk_latency_p50_ms": float(np.percentile(ms, 50)),
        "chunk_latency_p99_ms": float(np.percentile(ms, 99)),
        "chunk_latency_n": float(len(ms)),
    }


@dataclass(frozen=True)
class LearnerArgs(ServiceArgs):
    """Learner service settings."""

    learner_id: str = env_field("URSA_LEARNER_ID", "main")
    """Id of this learner in its liveliness token."""
    stats_hz: float = 2.0
    """How often metrics are published."""
    stream_stats_s: float = 600.0
    """Per-collector counters (``chunks/<id>`` …) are published for collectors heard from in
    this many seconds; totals cover every collector ever seen. Keeps the stats bounded when
    collectors come and go (compose re-creates them under new ids)."""
    segment_chunks: int = 2000
    """Chunks per MCAP replay segment before rotating to a new file."""
    replay_capacity: int = 2_000_000
    """Transitions the in-memory replay keeps (the MCAP segments keep everything)."""
    min_replay: int = 2000
    """Transitions in the replay before the first update (DayDreamer's train_fill)."""
    publish_every_s: float = 5.0
    """Seconds between two policy-weight publications."""
    checkpoint_every_s: float = 120.0
    """Seconds between two checkpoints (one is also written on SIGTERM)."""
    torch_threads: int = env_field("URSA_TORCH_THREADS", "1", int)
    """Intra-op threads of torch on the CPU (env URSA_TORCH_THREADS)."""
    max_updates: int = 0
    """Stop training after this many updates (0: never); ingestion goes on."""
    storage_retry_s: float = 5.0
    """After a failed write to the run directory (a full volume), retry this often; chunks
    received meanwhile stay in the replay and wait, in order, to be written."""
    max_unpersisted: int = 100_000
    """Chunks kept waiting for the disk at most; beyond, the oldest are kept in memory only."""


class LearnerService:
    """Learner process shell: messages in, core calls, messages out."""

    def __init__(self, args: LearnerArgs) -> None:
        self.args = args
        self.cfg = args.core
        validate_with(self.cfg)  # every message decoded is checked against the run's bounds
        self.skill_box = bounds.declared(self.cfg).skills
        """KDE draws for imagination are truncated to the feature function's skill box."""
        limit_threads(torch_threads=args.torch_threads)
        self.rt = ServiceRuntime("learner", args.learner_id, args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, "learner")
        self.config_hash = config_hash(self.cfg.learner)

        env = build_env(self.cfg, seed=0)
        obs_dim, act_dim = env.obs_dim, env.act_dim
        feat_in = int(env.feature_dims[self.cfg.feature_input_key])
        env.close()
        self.learner = Learner(self.cfg.learner, obs_dim, act_dim, feat_in, self.cfg.skill_dim)
        # `auto` is resolved by measuring this CPU; say what it gave
        self.log.info(
            "compute dtype %s (setting %s, %s)",
            dtype_name(self.learner.compute),
            self.cfg.learner.compute_dtype,
            self.learner.device,
        )
        self.replay = Replay(args.replay_capacity)
        self.ledger = IngestLedger()
        self.rng = np.random.default_rng(self.cfg.learner.seed + 1)
        self.ckpt_dir = RunDir(args.run.dir).checkpoints
        self.state_path = RunDir(args.run.dir).learner_state
        self.samples = 0
        """Transitions sampled for training so far (for the replay ratio)."""
        self.violation_rate: float | None = None
        """Exponential average of the admitted steps' violation (``ursa.safety_floor``)."""
        self._pace_base: tuple[int, int] | None = None
        """(inserted, samples) at this process's first update: the rate limiter's origin."""
        self.weights_version = 0
        self.metrics: dict[str, float] = {}
        self.lags: deque[int] = deque(maxlen=200)
        self.latencies: deque[tuple[float, float]] = deque(maxlen=2000)
        """(receipt on the monotonic clock, seconds from the chunk's send stamp to its receipt)
        of recent chunks; the stats report those of the last ``LATENCY_WINDOW_S``."""
        self.update_times: deque[float] = deque(maxlen=100)

        self.replay_dir = RunDir(args.run.dir).replay
        self.storage_errors = {"replay": 0, "checkpoint": 0}
        """Writes to the run directory that failed (OSError: a full volume, ENOSPC), by kind."""
        self.storage_error = ""
        """The last such failure, in words; empty once writes succeed again."""
        self.unpersisted: deque[pb.TransitionChunk] = deque()
        """Chunks in the replay that could not be written yet (oldest first)."""
        self.unpersisted_dropped = 0
        self._storage_retry_at = 0.0
        self.stale_tmp_removed = self._remove_stale_tmp()
        self._restore()
        self.writer = ReplayWriter(self.replay_dir, args.segment_chunks)

        self.inbox: queue.Queue[pb.TransitionChunk] = queue.Queue()
        self._replay_lock = threading.Lock()
        """Held while the ingest thread adds a chunk and while training samples a batch."""
        self._ingest_stop = threading.Event()
        self._ingest = threading.Thread(target=self._ingest_loop, name="ingest", daemon=True)
        self._snap_lock = threading.Lock()
        self._snapshot: pb.RepertoireSnapshot | None = None
        self._weights_bytes: bytes | None = None
        self._encoder_bytes: bytes | None = None
        t = self.rt.topics
        self.pub_weights = publisher(self.rt.session, t.weights, reliable=False)
        self.pub_encoder = publisher(self.rt.session, t.encoder, reliable=True)
        self.subs = [
            self.rt.session.declare_subscriber(
                t.transitions(),
                safe_handler(pb.TransitionChunk, self._on_chunk, self.rt.drops, args.run.run_id),
            ),
            self.rt.session.declare_subscriber(
                t.snapshot,
                safe_handler(
                    pb.RepertoireSnapshot, self._on_snapshot, self.rt.drops, args.run.run_id
                ),
            ),
        ]
        self.presence = Presence(self.rt.session, t.alive("collector"))
        self.queryables = [self.rt.session.declare_queryable(t.weights, self._on_weights_query)]
        if self.learned:
            self.queryables.append(
                self.rt.session.declare_queryable(t.encoder, self._on_encoder_query)
            )

    @property
    def learned(self) -> bool:
        return self.cfg.learner.mode == "ursa"

    # ---- persistence -----------------------------------------------------------------------
    def _remove_stale_tmp(self) -> int:
        """Temporary files of checkpoint writes cut short (the process was killed between
        atomic_write's create and rename): the checkpoint beside them is the previous complete
        one, which is what this process resumes from."""
        n = 0
        for p in sorted(self.ckpt_dir.glob(f"*{TEMP_SUFFIX}")) if self.ckpt_dir.is_dir() else []:
            try:
                p.unlink()
                n += 1
                self.log.warning(
                    "removed %s: a checkpoint write was cut short (process killed mid-write); "
                    "resuming from the previous complete checkpoint",
                    p.name,
                )
            except OSError as e:
                self.log.warning("could not remove stale %s: %s", p, e)
        return n

    def _storage_failed(self, what: str, e: OSError) -> None:
        self.storage_errors[what] += 1
        name = errno.errorcode.get(e.errno or 0, "OSError")
        full = e.errno in (errno.ENOSPC, errno.EDQUOT)
        msg = (
            f"run directory {self.args.run.dir} is full ({name}: {e.strerror or e}) writing the "
            f"{what}"
            if full
            else f"writing the {what} failed ({name}: {e.strerror or e})"
        )
        if what == "checkpoint":
            msg += "; the previous checkpoint is kept"
        else:
            msg += (
                "; segment cut back to its last complete chunk, chunks kept in memory and "
                f"written in order once the disk takes them (retry every "
                f"{self.args.storage_retry_s:g} s)"
            )
        if msg != self.storage_error:
            self.log.error("%s", msg)
        self.storage_error = msg
        self._storage_retry_at = time.monotonic() + self.args.storage_retry_s

    def _storage_recovered(self, what: str) -> None:
        if self.storage_error and not self.unpersisted:
            self.log.warning("run directory writable again (%s written)", what)
            self.storage_error = ""

    def _persist(self, chunk: pb.TransitionChunk) -> None:
        """Write one admitted chunk to the replay segments, after any that still wait."""
        if self.unpersisted:
            if len(self.unpersisted) >= self.args.max_unpersisted:
                self.unpersisted.popleft()
                self.unpersisted_dropped += 1
            self.unpersisted.append(chunk)
            self._retry_persist()
            return
        try:
            self.writer.write(chunk)
        except OSError as e:
            self.unpersisted.append(chunk)
            self._storage_failed("replay", e)

    def _retry_persist(self, force: bool = False) -> None:
        if not self.unpersisted or (not force and time.monotonic() < self._storage_retry_at):
            return
        n = 0
        while self.unpersisted:
            try:
                self.writer.write(self.unpersisted[0])
            except OSError as e:
                self._storage_failed("replay", e)
                return
            self.unpersisted.popleft()
            n += 1
        self.log.warning("replay writes resumed: %d waiting chunks written", n)
        self._storage_recovered("replay")

    def _restore(self) -> None:
        ckpt = RunDir(self.args.run.dir).checkpoint
        if ckpt.exists():
            self.learner.load_checkpoint(ckpt)
            state = json.loads(self.state_path.read_text()) if self.state_path.exists() else {}
            self.samples = int(state.get("samples", 0))
            self.weights_version = int(state.get("weights_version", self.learner.updates))
            self.log.info("resumed from checkpoint at %d updates", self.learner.updates)
        n = 0
        for chunk in read_all(self.replay_dir):
            self._admit(chunk, write=False)
            n += 1
        if n:
            self.log.info(
                "restored %d chunks (%d transitions) from %s", n, len(self.replay), self.replay_dir
            )

    def checkpoint(self) -> bool:
        """Write the checkpoint; False (logged, counted, the previous one kept) when the run
        directory refuses it, e.g. a full volume."""
        state = {
            "samples": self.samples,
            "weights_version": self.weights_version,
            "updates": self.learner.updates,
            "stamp": time.time(),
        }
        try:
            self.ckpt_dir.mkdir(parents=True, exist_ok=True)
            self.learner.save_checkpoint(RunDir(self.args.run.dir).checkpoint)
            atomic_write(self.state_path, json.dumps(state))
        except Exception as e:
            # torch.save reports a full disk as a RuntimeError of its zip writer, raised while
            # handling the OSError: look for the OSError in the chain
            cause: BaseException | None = e
            while cause is not None and not isinstance(cause, OSError):
                cause = cause.__cause__ or cause.__context__
            if cause is None:
                raise
            assert isinstance(cause, OSError)
            self._storage_failed("checkpoint", cause)
            return False
        self._storage_recovered("checkpoint")
        return True

    # ---- bus callbacks ---------------------------------------------------------------------
    def _on_chunk(self, msg: pb.TransitionChunk, key: str) -> None:
        self.latencies.append((time.monotonic(), time.time() - msg.header.stamp))
        obs = codec.from_array(msg.obs)
        if obs.ndim != 2 or obs.shape[0] == 0:
            raise codec.BadMessage(f"chunk obs of shape {obs.shape}")
        for name in CHUNK_FIELDS[1:]:
            a = codec.from_array(getattr(msg, name))
            if a.shape[:1] != obs.shape[:1]:
                raise codec.BadMessage(f"chunk {name} has {a.shape[:1]} rows, obs {obs.shape[0]}")
        self.inbox.put(msg)

    def _on_snapshot(self, msg: pb.RepertoireSnapshot, key: str) -> None:
        with self._snap_lock:
            self._snapshot = msg

    def _on_weights_query(self, query: zenoh.Query) -> None:
        if self._weights_bytes is not None:
            query.reply(self.rt.topics.weights, self._weights_bytes)

    def _on_encoder_query(self, query: zenoh.Query) -> None:
        if self._encoder_bytes is not None:
            query.reply(self.rt.topics.encoder, self._encoder_bytes)

    # ---- ingestion -------------------------------------------------------------------------
    def _admit(self, chunk: pb.TransitionChunk, write: bool = True) -> bool:
        arrays = {name: codec.from_array(getattr(chunk, name)) for name in CHUNK_FIELDS}
        n = int(arrays["obs"].shape[0])
        st = self.ledger.streams.get(chunk.collector_id)
        expected = st.next_seq if st is not None and st.incarnation == chunk.incarnation else None
        ok, _ = self.ledger.admit(
            chunk.collector_id,
            int(chunk.incarnation),
            int(chunk.seq),
            int(chunk.first_step),
            n,
            int(chunk.policy_version),
        )
        if not ok:
            return False
        if write and expected is not None and chunk.seq > expected:
            self.log.warning(
                "chunks %d..%d of collector %s (incarnation %d) never arrived",
                expected,
                chunk.seq - 1,
                chunk.collector_id,
                chunk.incarnation,
            )
        try:
            self.replay.add(chunk.collector_id, arrays, int(chunk.first_step))
        except ValueError as e:  # another env's or config's data: refuse, never crash
            self.rt.drops.add("incompatible")
            self.log.warning("refused chunk from %s: %s", chunk.collector_id, e)
            return False
        if n:  # the collectors' pooled violation rate, λ2's floor's input
            self.violation_rate = ema_rate(
                self.violation_rate,
                ~arrays["safe"].astype(bool),
                self.cfg.learner.lambda2_floor_window,
            )
        if write:
            self._persist(chunk)
            self.lags.append(max(0, self.weights_version - int(chunk.policy_version)))
        return True

    def drain(self) -> int:
        """Admit every chunk queued now, on the calling thread; returns how many."""
        n = 0
        while True:
            try:
                chunk = self.inbox.get_nowait()
            except queue.Empty:
                return n
            with self._replay_lock:
                self._admit(chunk)
            n += 1

    def _ingest_loop(self) -> None:
        """Decode, store and record chunks while an update runs (torch releases the GIL in its
        kernels), so that ingestion never waits for training."""
        while not self._ingest_stop.is_set():
            try:
                chunk = self.inbox.get(timeout=0.1)
            except queue.Empty:
                with self._replay_lock:
                    self._retry_persist()
                continue
            try:
                with self._replay_lock:
                    self._admit(chunk)
            except Exception:  # never let one chunk stop ingestion
                self.rt.drops.add("ingest_error")
                self.log.exception("chunk from %s not ingested", chunk.collector_id)

    # ---- training --------------------------------------------------------------------------
    def skill_snapshot(self) -> SkillSnapshot | None:
        with self._snap_lock:
            snap = self._snapshot
        if snap is None:
            return None
        skills = codec.from_array(snap.skills)
        if len(skills) < 2 or skills.shape[1] != self.cfg.skill_dim:
            return None
        if self.learned and snap.encoder_version != self.learner.vae_version:
            # skills encoded with another encoder version live in another space: wait for the
            # repertoire to re-encode (it receives every version we publish)
            return None
        inputs = codec.from_array(snap.inputs) if snap.HasField("inputs") else None
        return SkillSnapshot(
            skills=np.asarray(skills, np.float64),
            cov=np.asarray(codec.from_array(snap.cov), np.float64),
            delta=float(snap.delta),
            inputs=None if inputs is None or inputs.size == 0 else np.asarray(inputs, np.float64),
            version=int(snap.encoder_version),
            box=(np.asarray(self.skill_box.low), np.asarray(self.skill_box.high)),
            support=kde.support_radius(self.cfg.repertoire.support_radius, float(snap.delta)),
        )

    def can_train(self) -> bool:
        a, c = self.args, self.cfg.learner
        if a.max_updates and self.learner.updates >= a.max_updates:
            return False
        if len(self.replay) < a.min_replay:
            return False
        inserted = self.ledger.total_steps
        return self.samples + c.batch_size * c.seq_len <= c.train_ratio * inserted

    def train_once(self) -> bool:
        c = self.cfg.learner
        snap = self.skill_snapshot() if c.uses_skills else None
        if c.uses_skills and snap is None:
            return False
        t0 = time.perf_counter()
        with self._replay_lock:
            batch = self.replay.sample(c.batch_size, c.seq_len, self.rng, c.replay_unsafe)
        before = self.learner.vae_version
        metrics = self.learner.train_step(batch, snap, self.violation_rate)
        if self._pace_base is None:
            self._pace_base = (self.ledger.total_steps, self.samples)
        self.samples += c.batch_size * c.seq_len
        self.update_times.append(time.perf_counter() - t0)
        self.metrics = metrics
        if self.learned and self.learner.vae_version != before:
            self.publish_encoder()
        return True

    # ---- publishing ------------------------------------------------------------------------
    def publish_weights(self) -> None:
        self.weights_version = self.learner.updates
        msg = pb.PolicyWeights(
            header=self.rt.header(),
            version=self.weights_version,
            safetensors=self.learner.policy_weights_bytes(),
            config_hash=self.config_hash,
            updates=self.learner.updates,
        )
        self._weights_bytes = codec.encode(msg)
        self.pub_weights.put(self._weights_bytes)

    def encoder_bytes(self) -> bytes:
        assert self.learner.vae_pub is not None
        state = {
            k: v.detach().cpu().contiguous() for k, v in self.learner.vae_pub.state_dict().items()
        }
        return st_save(state, metadata={"version": str(self.learner.vae_version)})

    def publish_encoder(self) -> None:
        msg = pb.EncoderWeights(
            header=self.rt.header(),
            version=self.learner.vae_version,
            safetensors=self.encoder_bytes(),
            config_hash=self.config_hash,
        )
        self._encoder_bytes = codec.encode(msg)
        self.pub_encoder.put(self._encoder_bytes)
        self.log.info("published encoder version %d", self.learner.vae_version)

    def pace(self) -> tuple[float, bool]:
        """The rate limiter's budget (env steps all collectors may still insert) and whether it
        is engaged; see ``ursa.pace``. Before this process's first update the collectors may
        fill the prefill; from its first update on, the ratio is held over what was inserted
        and sampled since then (data that arrived while no learner trained is not owed)."""
        a, c, cc = self.args, self.cfg.learner, self.cfg.collector
        if a.max_updates and self.learner.updates >= a.max_updates:
            return math.inf, False
        slack = default_slack(c.batch_size, c.seq_len, c.train_ratio)
        if self._pace_base is None:
            # not training yet: the prefill may be collected; past it, a learner that cannot
            # train (no repertoire snapshot) holds nobody
            return float(a.min_replay - len(self.replay)), len(self.replay) < a.min_replay
        inserted0, samples0 = self._pace_base
        budget = insert_budget(
            self.ledger.total_steps - inserted0,
            self.samples - samples0,
            c.train_ratio,
            cc.pace_tolerance,
            slack,
        )
        return budget, True

    def paced_ratio(self) -> float:
        """Replay ratio since this process's first update (the ratio the limiter holds)."""
        if self._pace_base is None:
            return 0.0
        inserted0, samples0 = self._pace_base
        return (self.samples - samples0) / max(self.ledger.total_steps - inserted0, 1)

    def publish_stats(self) -> None:
        c = self.cfg.learner
        inserted = max(self.ledger.total_steps, 1)
        budget, engaged = self.pace()
        scalars: dict[str, float] = {
            "replay_steps": len(self.replay),
            "ingested_steps": self.ledger.total_steps,
            "collectors_seen": len(self.ledger.streams),
            "collectors_alive": len(self.presence.alive()),
            "updates": self.learner.updates,
            "policy_version": self.weights_version,
            "replay_ratio": self.samples / inserted,
            "replay_ratio_paced": self.paced_ratio(),
            "train_ratio_limit": c.train_ratio,
            "pace_budget": budget if np.isfinite(budget) else 1e12,
            "pace_engaged": float(engaged and self.cfg.collector.pace == "wait"),
            "updates_per_s": (
                len(self.update_times) / sum(self.update_times) if self.update_times else 0.0
            ),
            "policy_lag": float(np.mean(self.lags)) if self.lags else 0.0,
            "encoder_version": self.learner.vae_version,
            "inbox": self.inbox.qsize(),
            "storage_ok": float(not self.storage_error),
            "replay_write_errors": self.storage_errors["replay"],
            "checkpoint_errors": self.storage_errors["checkpoint"],
            "replay_unpersisted": len(self.unpersisted),
            "replay_unpersisted_dropped": self.unpersisted_dropped,
            "checkpoint_tmp_removed": self.stale_tmp_removed,
        }
        scalars.update(latency_stats(self.latencies, time.monotonic()))
        for k, v in self.metrics.items():
            if np.isfinite(v):
                scalars[k] = float(v)
        scalars.update(self.ledger.totals())
        for cid, st in self.ledger.recent(self.args.stream_stats_s).items():
            scalars[f"chunks/{cid}"] = st.chunks
            scalars[f"gaps/{cid}"] = st.gaps
            scalars[f"missing/{cid}"] = st.missing_chunks
            scalars[f"duplicates/{cid}"] = st.duplicates
            scalars[f"next_seq/{cid}"] = st.next_seq
        alive = sorted(Topics.last_chunk(k) for k in self.presence.alive())
        self.rt.publish_stats(
            scalars,
            labels={
                "mode": c.mode,
                "device": c.device,
                "collectors_alive": ",".join(alive),
                "storage_error": self.storage_error,
            },
        )

    # ---- loop ------------------------------------------------------------------------------
    def run(self) -> None:
        a = self.args
        t = self.rt.topics
        snap = query_one(self.rt.session, t.snapshot, pb.RepertoireSnapshot, timeout_s=1.0)
        if snap is not None:
            self._on_snapshot(snap, t.snapshot)
        self.publish_weights()
        if self.learned:
            self.publish_encoder()
        print(
            f"LEARNER READY mode={self.cfg.learner.mode} updates={self.learner.updates}", flush=True
        )
        last_stats = last_weights = last_ckpt = time.monotonic()
        self._ingest.start()
        while not self.rt.stop.is_set():
            trained = self.can_train() and self.train_once()
            if not trained:
                self.rt.stop.wait(0.02)
            now = time.monotonic()
            if now - last_stats >= 1.0 / a.stats_hz:
                self.publish_stats()
                last_stats = now
            if trained and now - last_weights >= a.publish_every_s:
                self.publish_weights()
                last_weights = now
            if now - last_ckpt >= a.checkpoint_every_s:
                self.checkpoint()
                last_ckpt = now

    def close(self) -> None:
        self.presence.undeclare()
        handles: list[Any] = [*self.subs, *self.queryables]
        for h in handles:
            try:
                h.undeclare()
            except Exception:
                pass
        self._ingest_stop.set()
        if self._ingest.is_alive():
            self._ingest.join(timeout=10.0)
        self.drain()
        self._retry_persist(force=True)
        try:
            self.writer.close()
        except OSError as e:  # the footer did not fit: the chunks before it are readable
            self._storage_failed("replay", e)
        if self.unpersisted:
            self.log.error(
                "%d chunks could not be written to %s before exit (in memory only)",
                len(self.unpersisted),
                self.replay_dir,
            )
        self.checkpoint()
        self.rt.close()
