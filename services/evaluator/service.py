"""Evaluator: an evaluation collector that runs one skill per request and feeds no replay.

Queryable:   ursa/{run}/evaluator/evaluate (EvaluateRequest -> EvaluateReply), one at a time
Subscribes:  ursa/{run}/learner/weights (PolicyWeights, latest; also queried when needed)
             ursa/{run}/repertoire/snapshot (RepertoireSnapshot, latest: Σ and δ of the metric)
Publishes:   ursa/{run}/evaluator/stats (Stats)
Liveliness:  ursa/{run}/alive/evaluator/{id}

Each request builds a fresh environment (``ursa.config.build_env``, the collectors' factory)
with the requested damage and seed, acts ``steps`` control steps with the skill fixed using the
same policy as the collectors (``ursa.policy.Policy`` with the learner's latest weights; the
collectors' uniformly random behaviour before any weights exist), and replies with the mean φ,
its Mahalanobis distance to the skill in the repertoire's metric, δ, the return and the number
of unsafe steps. Requests are served in arrival order, one at a time. A request the evaluator
cannot accept is answered with ``error`` starting with ``invalid:``; a missing peer (no
snapshot yet) or a failure with ``unavailable:``.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import zenoh

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import checked_decode, query_one, reason_of, safe_handler, validate_with
from services.common.config import BusConfig, RunConfig, config_hash, save_resolved
from services.common.runtime import ServiceRuntime
from services.dashboard.live import SnapshotView
from services.evaluator.acting import Acting, PolicyActing, RandomActing
from services.evaluator.rollout import allowed_damages, run_skill
from ursa import scoring
from ursa.config import Config, build_env
from ursa.policy import Policy


@dataclass(frozen=True)
class EvaluatorArgs:
    """Evaluator service settings."""

    core: Config = field(default_factory=Config)
    bus: BusConfig = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)
    collector_id: str = os.environ.get("URSA_EVALUATOR_ID", "eval")
    """Id of this evaluation collector (its liveliness token is ``alive/evaluator/{id}``)."""
    seed: int = int(os.environ.get("URSA_SEED", "0"))
    """Seed of the evaluations that give none (the n-th such evaluation uses seed + n)."""
    max_steps: int = 5000
    """Largest ``steps`` a request may ask for."""
    explore: bool = scoring.EXPLORE
    """Sample actions (as collectors do) instead of taking the policy's mode."""
    stats_hz: float = 1.0
    """How often stats are published."""


class Evaluator:
    """The evaluator process; :meth:`handle` answers one request (also callable from tests)."""

    def __init__(self, args: EvaluatorArgs) -> None:
        self.args = args
        self.cfg = args.core
        validate_with(self.cfg)  # every message decoded is checked against the run's bounds
        self.rt = ServiceRuntime("evaluator", args.collector_id, args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, f"evaluator-{args.collector_id}")
        torch.set_num_threads(1)
        self.feature_key = self.cfg.feature_input_key
        self.skill_dim = self.cfg.skill_dim
        self.damages = allowed_damages(self.cfg.env)
        probe = build_env(self.cfg, seed=args.seed)
        self.obs_dim, self.act_dim = probe.obs_dim, probe.act_dim
        self.feat_in_dim = int(probe.feature_dims[self.feature_key])
        probe.close()
        self.policy = Policy(
            self.cfg.learner,
            self.obs_dim,
            self.act_dim,
            self.skill_dim,
            feat_in_dim=self.feat_in_dim,
            seed=args.seed,
        )
        self.policy_version = 0
        self.config_hash = config_hash(self.cfg.learner)
        self._lock = threading.Lock()
        self._pending: pb.PolicyWeights | None = None
        self.snapshot: SnapshotView | None = None
        self.evaluations = 0
        self.failures = 0
        self.busy = False
        self.last: dict[str, float] = {}

        t = self.rt.topics
        drops = self.rt.drops
        self.subs = [
            self.rt.session.declare_subscriber(
                t.weights, safe_handler(pb.PolicyWeights, self._on_weights, drops, args.run.run_id)
            ),
            self.rt.session.declare_subscriber(
                t.snapshot,
                safe_handler(pb.RepertoireSnapshot, self._on_snapshot, drops, args.run.run_id),
            ),
        ]
        self.queryable = self.rt.session.declare_queryable(
            t.evaluate, zenoh.handlers.FifoChannel(64)
        )

    # ---- inputs ----------------------------------------------------------------------------
    def _on_weights(self, msg: pb.PolicyWeights, key: str) -> None:
        with self._lock:
            if self._pending is None or msg.version > self._pending.version:
                self._pending = msg

    def _on_snapshot(self, msg: pb.RepertoireSnapshot, key: str) -> None:
        view = SnapshotView.from_msg(msg)
        with self._lock:
            cur = self.snapshot
            if cur is None or view.version > cur.version or view.stamp > cur.stamp:
                self.snapshot = view

    def _load_weights(self) -> None:
        """Apply the newest weights received; with none yet, ask the learner once."""
        if self.policy_version == 0 and self._pending is None:
            msg = query_one(
                self.rt.session, self.rt.topics.weights, pb.PolicyWeights, timeout_s=1.0
            )
            if msg is not None:
                self._on_weights(msg, self.rt.topics.weights)
        with self._lock:
            msg, self._pending = self._pending, None
        if msg is None or msg.version <= self.policy_version:
            return
        if msg.config_hash != self.config_hash:
            self.rt.drops.add("config_mismatch")
            self.log.warning(
                "refused weights %d: learner config %s, mine %s",
                msg.version,
                msg.config_hash,
                self.config_hash,
            )
            return
        try:
            self.policy.load_weights_bytes(msg.safetensors, version=int(msg.version))
        except Exception as e:  # wrong shapes or corrupt bytes: keep the current policy
            self.rt.drops.add("bad_weights")
            self.log.warning("refused weights %d: %s", msg.version, e)
            return
        self.policy_version = int(msg.version)
        self.log.info("policy weights version %d", self.policy_version)

    def _metric(self) -> SnapshotView | None:
        if self.snapshot is None:
            msg = query_one(
                self.rt.session, self.rt.topics.snapshot, pb.RepertoireSnapshot, timeout_s=1.0
            )
            if msg is not None:
                try:
                    self._on_snapshot(msg, self.rt.topics.snapshot)
                except codec.BadMessage as e:
                    self.rt.drops.add("malformed")
                    self.log.warning("bad snapshot reply: %s", e)
        return self.snapshot

    # ---- requests --------------------------------------------------------------------------
    def validate(self, req: pb.EvaluateRequest) -> tuple[np.ndarray, str]:
        """(skill (D,), damage) of a request; raises ValueError with the reason."""
        try:
            skill = np.asarray(codec.from_array(req.skill), np.float64)
        except codec.BadMessage as e:
            raise ValueError(f"skill: {e}") from e
        if skill.shape != (self.skill_dim,):
            raise ValueError(f"skill of shape {skill.shape}, expected ({self.skill_dim},)")
        if not np.all(np.isfinite(skill)):
            raise ValueError("skill must be finite")
        if not 1 <= req.steps <= self.args.max_steps:
            raise ValueError(f"steps={req.steps} outside 1..{self.args.max_steps}")
        if req.damage not in self.damages:
            raise ValueError(
                f"damage {req.damage!r} not one of {', '.join(self.damages[1:])} "
                f"on env {self.cfg.env}"
            )
        return skill, "" if req.damage == "none" else req.damage

    def handle(self, req: pb.EvaluateRequest) -> pb.EvaluateReply:
        reply = pb.EvaluateReply(header=self.rt.header())
        try:
            skill, damage = self.validate(req)
        except ValueError as e:
            reply.error = f"invalid: {e}"
            return reply
        snap = self._metric()
        if snap is None:
            reply.error = "unavailable: no repertoire snapshot yet (it sets the metric and δ)"
            return reply
        if snap.dim != self.skill_dim:
            reply.error = f"unavailable: snapshot dimension {snap.dim} != {self.skill_dim}"
            return reply
        self._load_weights()
        seed = int(req.seed) if req.has_seed else self.args.seed + self.evaluations
        rng = np.random.default_rng(seed)
        acting: Acting = (
            PolicyActing(self.policy, rng, self.args.explore)
            if self.policy_version > 0
            else RandomActing(self.act_dim, rng)
        )
        self.busy = True
        env = build_env(self.cfg, seed=seed, damage=damage)
        try:
            res = run_skill(env, acting, skill, int(req.steps), self.feature_key, snap.cov)
        except Exception as e:
            self.failures += 1
            self.log.exception("evaluation failed")
            reply.error = f"unavailable: evaluation failed: {e}"
            return reply
        finally:
            env.close()
            self.busy = False
        if not (np.isfinite(res.distance) and np.isfinite(res.ret)):
            self.failures += 1
            reply.error = (
                f"unavailable: policy version {acting.version} produced non-finite "
                "actions or features"
            )
            return reply
        self.evaluations += 1
        reply.achieved.CopyFrom(codec.to_array(res.achieved.astype(np.float32)))
        reply.distance = res.distance
        reply.delta = snap.delta
        reply.ret = res.ret
        reply.violations = res.violations
        reply.steps = res.steps
        reply.policy_version = acting.version
        self.last = {
            "last_distance": res.distance,
            "last_return": res.ret,
            "last_steps_per_s": res.steps / max(res.elapsed_s, 1e-9),
            "last_within_delta": float(res.distance <= snap.delta),
        }
        self.log.info(
            "evaluated skill %s for %d steps (damage %r, policy %d): distance %.3f, "
            "δ %.3f, return %.2f, %d unsafe",
            np.round(skill, 3).tolist(),
            res.steps,
            damage or "none",
            acting.version,
            res.distance,
            snap.delta,
            res.ret,
            res.violations,
        )
        return reply

    def _serve(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            req = checked_decode(pb.EvaluateRequest, payload, run_id=self.args.run.run_id)
        except codec.BadMessage as e:
            self.rt.drops.add(reason_of(e), self.rt.topics.evaluate, codec.claimed_sender(payload))
            reply = pb.EvaluateReply(header=self.rt.header(), error=f"invalid: {e}")
        else:
            reply = self.handle(req)
        query.reply(self.rt.topics.evaluate, codec.encode(reply))

    def run(self) -> None:
        self._load_weights()
        print(f"EVALUATOR READY {self.args.collector_id}", flush=True)
        last_stats = 0.0
        while not self.rt.stop.is_set():
            query = self.queryable.try_recv()
            if query is not None:
                try:
                    self._serve(query)
                except Exception:  # a failed reply must not stop the evaluator
                    self.log.exception("cannot answer an evaluation query")
                finally:
                    del query  # finalizes the query (tells the requester no more replies come)
            else:
                self.rt.stop.wait(0.02)
            now = time.monotonic()
            if now - last_stats >= 1.0 / self.args.stats_hz:
                self.rt.publish_stats(
                    {
                        "evaluations": self.evaluations,
                        "failures": self.failures,
                        "busy": float(self.busy),
                        "policy_version": self.policy_version,
                        "max_steps": self.args.max_steps,
                        **self.last,
                    },
                    labels={"env": self.cfg.env, "feature": self.cfg.feature},
                )
                last_stats = now

    def close(self) -> None:
        for h in [*self.subs, self.queryable]:
            try:
                h.undeclare()  # type: ignore[attr-defined]
            except Exception:
                pass
        self.rt.close()
