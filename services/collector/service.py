"""Collector: runs one reset-free environment with the current policy (paper Algorithm 1).

Subscribes:  ursa/{run}/learner/weights (PolicyWeights, latest; also queried at start)
             ursa/{run}/learner/encoder (EncoderWeights, latest)
             ursa/{run}/learner/stats (Stats: the rate limiter's budget, ``ursa.pace``)
Queries:     ursa/{run}/repertoire/sample (SkillRequest -> SkillReply), every T steps
Publishes:   ursa/{run}/collector/transitions/{cid} (TransitionChunk, BLOCK)
             ursa/{run}/collector/features/{cid} (SafeFeatures, BLOCK)
             ursa/{run}/collector/stats/{cid} (Stats, may drop)
Liveliness:  ursa/{run}/alive/collector/{cid}; watches ursa/{run}/alive/learner/* (rate limiter)
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import (
    Presence,
    checked_decode,
    publisher,
    query_one,
    safe_handler,
    validate_with,
)
from services.common.config import (
    ServiceArgs,
    config_hash,
    env_field,
    save_resolved,
)
from services.common.runtime import ServiceRuntime
from services.common.weights import apply_weights
from ursa.acting import Acting, ActingConfig, Chunk
from ursa.config import PREFILL, build_env
from ursa.pace import PaceGate
from ursa.policy import Policy
from ursa.rundir import RunDir, atomic_write
from ursa.threads import limit_threads


def default_collector_id() -> str:
    """URSA_COLLECTOR_ID, else the host name (unique per container when scaled)."""
    cid = os.environ.get("URSA_COLLECTOR_ID") or os.uname().nodename
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in cid)


@dataclass(frozen=True)
class CollectorArgs(ServiceArgs):
    """Collector service settings."""

    collector_id: str = field(default_factory=default_collector_id)
    """Unique id of this collector (env URSA_COLLECTOR_ID, default: host name)."""
    seed: int = env_field("URSA_SEED", "0", int)
    """Seed of the environment and of the exploration noise."""
    backlog_chunks: int = 4000
    """Chunks (and feature batches) kept while nobody subscribes (learner or router down); sent
    in order once a subscriber matches again. The oldest are dropped beyond this."""
    resend_s: float = 30.0
    """Chunks put in this many seconds before the subscribers went away (the router lost) are
    put again when one matches again: a put into a link that is dead but not yet known to be
    vanishes silently, and the learner drops the copies that did arrive (by sequence number).
    Well above the link's lease (Zenoh's default 10 s): a dead link is noticed only after the
    lease, the keep-alive period and the scheduling of a loaded host (measured: 10 s lost 4
    chunks of a collector whose network was cut for 30 s; docs/deploy.md)."""
    max_steps: int = 0
    """Stop after this many control steps (0: run until stopped)."""
    realtime_factor: float = 0.0
    """Throttle to this multiple of real time (1.0 = 20 Hz control); 0 runs as fast as possible."""


class Collector:
    """One collector process: env + policy, publishing chunks, features and stats."""

    def __init__(self, args: CollectorArgs) -> None:
        self.args = args
        self.cfg = args.core
        validate_with(self.cfg)  # every message decoded is checked against the run's bounds
        self.cid = args.collector_id
        self.rt = ServiceRuntime("collector", self.cid, args.bus, args.run)
        self.log = self.rt.log
        t = self.rt.topics
        self.incarnation = self._next_incarnation()
        save_resolved(args, args.run, f"collector-{self.cid}")

        self.env = build_env(self.cfg, seed=args.seed)
        self.feature_key = self.cfg.feature_input_key
        if self.feature_key not in self.env.feature_dims:
            raise SystemExit(
                f"env {self.cfg.env} has no feature {self.feature_key!r}; "
                f"it has {sorted(self.env.feature_dims)}"
            )
        self.skill_dim = self.cfg.skill_dim
        self.task = self.cfg.a1.task if self.cfg.env == "a1" else "point"
        self.damage = (self.cfg.a1.damage or "") if self.cfg.env == "a1" else ""
        self.rng = np.random.default_rng(args.seed + 7919 * self.incarnation)
        limit_threads()
        self.policy = Policy(
            self.cfg.learner,
            self.env.obs_dim,
            self.env.act_dim,
            self.skill_dim,
            feat_in_dim=int(self.env.feature_dims[self.feature_key]),
            seed=args.seed,
        )
        self.acting = Acting(
            self.env,
            self.policy,
            ActingConfig(
                feature=self.feature_key,
                skill_period=self.cfg.collector.skill_period,
                chunk_len=self.cfg.collector.chunk_len,
                stamps=True,
                random_scale=self.cfg.collector.random_scale,
            ),
            self.rng,
            seed=args.seed,
        )
        """The acting loop (``ursa.acting``): skill, carry, sanitising, chunks, rescues."""
        self.config_hash = config_hash(self.cfg.learner)

        self.pub_chunks = publisher(self.rt.session, t.transitions(self.cid), reliable=True)
        self.pub_features = publisher(self.rt.session, t.features(self.cid), reliable=True)
        self.backlog = {
            "chunks": deque[bytes](maxlen=args.backlog_chunks),
            "features": deque[bytes](maxlen=args.backlog_chunks),
        }
        self.backlog_dropped = 0
        self._recent_chunks: deque[tuple[float, bytes]] = deque()  # (put at, payload)
        self._route_lost = threading.Event()
        self._match_listener = self.pub_chunks.declare_matching_listener(self._on_matching)
        self._weights_lock = threading.Lock()
        self._pending_weights: pb.PolicyWeights | None = None
        self._pending_skill: np.ndarray | None = None
        self.sub_weights = self.rt.session.declare_subscriber(
            t.weights,
            safe_handler(pb.PolicyWeights, self._on_weights, self.rt.drops, args.run.run_id),
        )
        self.gate = PaceGate(
            mode=self.cfg.collector.pace, allowance=float(PREFILL[self.cfg.preset])
        )
        """The rate limiter: waits while a live learner is behind its replay ratio."""
        self.learner_presence = Presence(self.rt.session, t.alive("learner"))
        self._presence_checked = 0.0
        self.sub_pace = self.rt.session.declare_subscriber(
            t.learner_stats,
            safe_handler(pb.Stats, self._on_learner_stats, self.rt.drops, args.run.run_id),
        )

        self.policy_version = 0
        self.skill_source = "none"
        self.seq = 0
        self.feat_seq = 0
        self.ret_window: deque[float] = deque(maxlen=1000)
        self.unsafe_window: deque[bool] = deque(maxlen=self.cfg.collector.violation_window)
        self.total_unsafe = 0
        self.rescues = 0
        self.last_info: dict[str, Any] = {}

    # ---- setup helpers -------------------------------------------------------------------
    def _next_incarnation(self) -> int:
        path = RunDir(self.args.run.dir).collector_file(self.cid)
        n = 0
        if path.exists():
            try:
                n = int(json.loads(path.read_text()).get("incarnation", -1)) + 1
            except (ValueError, OSError):
                n = 0
        atomic_write(path, json.dumps({"incarnation": n, "started": time.time()}))
        return n

    # ---- bus callbacks -------------------------------------------------------------------
    def _on_weights(self, msg: pb.PolicyWeights, key: str) -> None:
        with self._weights_lock:
            if self._pending_weights is None or msg.version > self._pending_weights.version:
                self._pending_weights = msg

    def _on_learner_stats(self, msg: pb.Stats, key: str) -> None:
        sc = msg.scalars
        if "pace_budget" not in sc:
            return
        self.gate.hear(
            float(sc["pace_budget"]),
            int(sc.get("collectors_alive", 1)),
            bool(sc.get("pace_engaged", 0.0)),
        )

    def _check_learner(self, now: float) -> None:
        if now - self._presence_checked >= 0.1:
            self.gate.learner(bool(self.learner_presence.alive()))
            self._presence_checked = now

    def _wait_for_pace(self, sps: float) -> None:
        """Hold the env while the rate limiter's gate is closed (stats keep flowing)."""
        self._check_learner(time.monotonic())
        if self.gate.open():
            return
        t0 = last = time.monotonic()
        while not self.rt.stop.is_set() and not self.gate.open():
            self.rt.stop.wait(0.005)
            now = time.monotonic()
            self._check_learner(now)
            if now - last >= 1.0 / self.cfg.collector.stats_hz:
                self._publish_stats(0.0)
                last = now
            self._maybe_load_weights()
        self.gate.waited_s += time.monotonic() - t0

    def _maybe_load_weights(self) -> None:
        with self._weights_lock:
            msg, self._pending_weights = self._pending_weights, None
        self.policy_version = apply_weights(
            msg, self.policy, self.policy_version, self.config_hash, self.rt.drops, self.log
        )

    def _request_skill(self) -> None:
        """Ask the repertoire for a KDE skill without waiting: the reply lands in a slot that the
        loop picks up (the robot keeps its previous skill meanwhile)."""
        req = pb.SkillRequest(header=self.rt.header(), n=1)
        try:
            self.rt.session.get(
                self.rt.topics.sample, self._on_skill_reply, payload=codec.encode(req), timeout=2.0
            )
        except Exception as e:  # a closed session at shutdown
            self.log.debug("skill request failed: %s", e)

    def _on_skill_reply(self, reply: Any) -> None:
        if reply.ok is None:
            return
        try:
            msg = checked_decode(pb.SkillReply, reply.ok.payload.to_bytes())
            if msg.error:
                return
            skills = codec.from_array(msg.skills)
        except codec.BadMessage as e:
            self.rt.drops.add("malformed")
            self.log.warning("bad skill reply: %s", e)
            return
        if skills.shape != (1, self.skill_dim) or not np.all(np.isfinite(skills)):
            self.rt.drops.add("invalid")
            return
        with self._weights_lock:
            self._pending_skill = skills[0].astype(np.float32)

    def _maybe_take_skill(self) -> None:
        with self._weights_lock:
            z, self._pending_skill = self._pending_skill, None
        if z is not None:
            self.acting.skill = z
            self.skill_source = "kde"

    # ---- acting --------------------------------------------------------------------------
    @property
    def step_count(self) -> int:
        """Env steps taken."""
        return self.acting.step_count

    @property
    def skill(self) -> np.ndarray:
        """The skill being executed (D,)."""
        return self.acting.skill

    def run(self) -> None:
        cfg = self.cfg.collector
        t = self.rt.topics
        existing = query_one(self.rt.session, t.weights, pb.PolicyWeights, timeout_s=1.0)
        if existing is not None:
            self._on_weights(existing, t.weights)
        last_stats = 0.0
        stats_period = 1.0 / cfg.stats_hz
        t_start = time.monotonic()
        steps_at_last_stats, time_at_last_stats = 0, time.monotonic()
        sps = 0.0
        while not self.rt.stop.is_set():
            if self.args.max_steps and self.step_count >= self.args.max_steps:
                break
            self._wait_for_pace(sps)
            self.gate.stepped()
            if self.acting.skill_due():
                self._request_skill()
            self._maybe_take_skill()
            self._maybe_load_weights()
            # uniformly random actions until the first trained weights arrive (the prefill)
            res = self.acting.step(random=self.policy_version <= 0)
            for chunk in res.chunks:
                self._publish_chunk(chunk)
            info = res.info
            safe = bool(info["safe"])
            self.ret_window.append(res.reward)
            self.unsafe_window.append(not safe)
            self.total_unsafe += int(not safe)
            self.rescues = int(info.get("rescues", 0))
            self.last_info = info
            now = time.monotonic()
            if now - last_stats >= stats_period:
                dt = now - time_at_last_stats
                if dt > 0.5:
                    sps = (self.step_count - steps_at_last_stats) / dt
                    steps_at_last_stats, time_at_last_stats = self.step_count, now
                self._publish_stats(sps)
                last_stats = max(last_stats + stats_period, now - stats_period)
            if self.args.realtime_factor > 0:
                target = t_start + self.step_count * 0.05 / self.args.realtime_factor
                delay = target - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
        for chunk in self.acting.flush():
            self._publish_chunk(chunk)
        self._publish_stats(sps)

    def _publish_chunk(self, chunk: Chunk) -> None:
        msg = pb.TransitionChunk(
            header=self.rt.header(),
            collector_id=self.cid,
            seq=self.seq,
            first_step=chunk.first_step,
            policy_version=self.policy_version,
            incarnation=self.incarnation,
            task=self.task,
            damage=self.damage,
            **{k: codec.to_array(v) for k, v in chunk.data.items()},
        )
        self._send("chunks", self.pub_chunks, codec.encode(msg))
        self.seq += 1
        safe_feats = chunk.archive_features(self.cfg.collector.archive_window)
        if len(safe_feats):
            fm = pb.SafeFeatures(
                header=self.rt.header(),
                collector_id=self.cid,
                seq=self.feat_seq,
                features=codec.to_array(safe_feats),
            )
            self._send("features", self.pub_features, codec.encode(fm))
            self.feat_seq += 1

    def _on_matching(self, status: Any) -> None:
        if not status.matching:
            self._route_lost.set()

    def _send(self, stream: str, pub: Any, payload: bytes) -> None:
        """Put now if a subscriber matches, else keep it (bounded) until one does. After the
        chunks' route was lost, the chunks put just before it are queued again first."""
        q = self.backlog[stream]
        if stream == "chunks" and self._route_lost.is_set():
            self._route_lost.clear()
            self.log.warning(
                "chunk route lost (learner or router gone): the %d chunks put in the last "
                "%g s go first when it is back",
                len(self._recent_chunks),
                self.args.resend_s,
            )
            q.extendleft(reversed([p for _, p in self._recent_chunks]))
            self._recent_chunks.clear()
        if not pub.matching_status.matching:
            if len(q) == q.maxlen:
                self.backlog_dropped += 1
            q.append(payload)
            return
        while q:
            self._put(stream, pub, q.popleft())
        self._put(stream, pub, payload)

    def _put(self, stream: str, pub: Any, payload: bytes) -> None:
        pub.put(payload)
        if stream == "chunks":
            now = time.monotonic()
            self._recent_chunks.append((now, payload))
            while self._recent_chunks and self._recent_chunks[0][0] < now - self.args.resend_s:
                self._recent_chunks.popleft()

    def _publish_stats(self, sps: float) -> None:
        n = max(len(self.unsafe_window), 1)
        arrays: dict[str, np.ndarray] = {"skill": self.skill}
        for k in ("joint_angles", "base_position", "base_orientation"):
            if k in self.last_info:
                arrays[k] = np.asarray(self.last_info[k], np.float32)
        self.rt.publish_stats(
            {
                "steps": self.step_count,
                "steps_per_s": sps,
                "chunks": self.seq,
                "return_mean": float(np.mean(self.ret_window)) if self.ret_window else 0.0,
                "violation_rate": sum(self.unsafe_window) / n,
                "unsafe_total": self.total_unsafe,
                "rescues": self.rescues,
                "policy_version": self.policy_version,
                "incarnation": self.incarnation,
                "backlog_chunks": len(self.backlog["chunks"]),
                "backlog_dropped": self.backlog_dropped,
                "nonfinite_actions": self.acting.nonfinite_actions,
                "pace_waiting": float(not self.gate.open()),
                "pace_wait_s": self.gate.waited_s,
            },
            labels={
                "env": self.cfg.env,
                "task": self.task,
                "damage": self.damage or "none",
                "skill_source": self.skill_source,
            },
            arrays=arrays,
        )

    def close(self) -> None:
        for h in (
            self._match_listener,
            self.sub_weights,
            self.sub_pace,
            self.learner_presence,
            self.pub_chunks,
            self.pub_features,
        ):
            try:
                h.undeclare()
            except Exception:
                pass
        self.env.close()
        self.rt.close()
