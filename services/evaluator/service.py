"""Evaluator: an evaluation collector that runs one skill per request and feeds no replay.

Queryable:   ursa/{run}/evaluator/evaluate (EvaluateRequest -> EvaluateReply), one at a time
             ursa/{run}/evaluator/adapt/{id} (AdaptRequest -> AdaptJob: start an adaptation)
             ursa/{run}/evaluator/adapt_job/{id} (AdaptQuery -> AdaptJob: a job's state)
Subscribes:  ursa/{run}/learner/weights (PolicyWeights, latest; also queried when needed)
             ursa/{run}/repertoire/snapshot (RepertoireSnapshot, latest: Σ and δ of the metric)
Publishes:   ursa/{run}/evaluator/stats (Stats)
             ursa/{run}/evaluator/adapt_state/{id} (AdaptJob, at every change of a job)
Liveliness:  ursa/{run}/alive/evaluator/{id}

Each request builds a fresh environment (``ursa.config.build_env``, the collectors' factory)
with the requested damage and seed, acts ``steps`` control steps with the skill fixed using the
same policy as the collectors (``ursa.policy.Policy`` with the learner's latest weights; the
collectors' uniformly random behaviour before any weights exist), and replies with the mean φ,
its Mahalanobis distance to the skill in the repertoire's metric, δ, the return and the number
of unsafe steps. Requests are served in arrival order, one at a time. A request the evaluator
cannot accept is answered with ``error`` starting with ``invalid:``; a missing peer (no
snapshot yet) or a failure with ``unavailable:``.

Adaptation jobs (docs/adapt.md): Intelligent Trial and Error (:mod:`ursa.adapt`) over the N_z
most distinct skills of the latest snapshot, one job at a time (a second is refused with
``busy:``). A job first measures the intact return of each skill (ITE's map; cached in
``<run>/eval/adapt/`` per policy version, skills and T, so it is measured once), then runs one
trial per loop turn on the damaged robot (a fresh env per trial, rescue off) until ITE's
stopping rule, the budget or the map is exhausted. Evaluations are served between the steps of
a job; the policy's weights are held for the job's duration so every trial uses one policy.
Every change is written to ``<run>/eval/adapt/jobs/<job id>.json`` and published; a job found
unfinished when the evaluator starts is marked ``lost``.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from google.protobuf import json_format

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import checked_decode, query_one, reason_of, safe_handler, validate_with
from services.common.config import (
    ServiceArgs,
    config_hash,
    env_field,
    save_resolved,
)
from services.common.live import SnapshotView
from services.common.runtime import ServiceRuntime
from services.common.weights import apply_weights
from ursa import adapt, scoring
from ursa.adapt import ITEParams, Observations, SkillMap
from ursa.config import build_env
from ursa.envs import allowed_damages
from ursa.envs.base import ResetFreeEnv
from ursa.eval.rollout import SkillRun, farthest_point_sampling, run_skill
from ursa.policy import Policy
from ursa.rundir import atomic_write
from ursa.threads import limit_threads

MAPPING, ADAPTING, DONE, FAILED, LOST = "mapping", "adapting", "done", "failed", "lost"
FINAL_STATES = (DONE, FAILED, LOST)
N_JOINTS = 12


@dataclass(frozen=True)
class EvaluatorArgs(ServiceArgs):
    """Evaluator service settings."""

    collector_id: str = env_field("URSA_EVALUATOR_ID", "eval")
    """Id of this evaluation collector (its liveliness token is ``alive/evaluator/{id}``)."""
    seed: int = env_field("URSA_SEED", "0", int)
    """Seed of the evaluations that give none (the n-th such evaluation uses seed + n)."""
    max_steps: int = 5000
    """Largest ``steps`` a request may ask for."""
    explore: bool = scoring.EXPLORE
    """Sample actions (as collectors do) instead of taking the policy's mode."""
    stats_hz: float = 1.0
    """How often stats are published."""
    max_adapt_budget: int = 200
    """Largest trial budget of an adaptation job."""
    max_adapt_skills: int = 5000
    """Largest map of an adaptation job (skills measured intact, one rollout each)."""


@dataclass
class AdaptRun:
    """The evaluator's side of one adaptation job (its published state is ``job``)."""

    job: pb.AdaptJob
    skills: np.ndarray
    """Map skills (N, D)."""
    ids: np.ndarray
    """Their repertoire ids (N,)."""
    prior: np.ndarray
    """Intact returns (N,), filled row by row while mapping."""
    params: ITEParams
    damage: str
    frozen: tuple[int, ...]
    steps: int
    seed: int
    cov: np.ndarray
    """Σ of the snapshot the map came from (the metric of the achieved-skill distance)."""
    cache: Path
    obs: Observations = field(default_factory=Observations)
    smap: SkillMap | None = None
    next_row: int | None = None

    @property
    def active(self) -> bool:
        return self.job.state not in FINAL_STATES


class Evaluator:
    """The evaluator process; :meth:`handle` answers one request (also callable from tests)."""

    def __init__(self, args: EvaluatorArgs) -> None:
        self.args = args
        self.cfg = args.core
        validate_with(self.cfg)  # every message decoded is checked against the run's bounds
        self.rt = ServiceRuntime("evaluator", args.collector_id, args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, f"evaluator-{args.collector_id}")
        limit_threads()
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
        eid = args.collector_id
        self.adapt_queryable = self.rt.session.declare_queryable(
            t.adapt(eid), zenoh.handlers.FifoChannel(16)
        )
        self.adapt_job_queryable = self.rt.session.declare_queryable(
            t.adapt_job(eid), zenoh.handlers.FifoChannel(64)
        )
        self.jobs_dir = adapt.adapt_dir(args.run.dir) / "jobs"
        self.job: AdaptRun | None = None
        self.adapt_trials = 0
        self.lost_jobs = self._mark_lost()

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
        """Apply the newest weights received; with none yet, ask the learner once. Held while
        an adaptation job runs: all its trials and its map use one policy."""
        if self.job is not None and self.job.active:
            return
        if self.policy_version == 0 and self._pending is None:
            msg = query_one(
                self.rt.session, self.rt.topics.weights, pb.PolicyWeights, timeout_s=1.0
            )
            if msg is not None:
                self._on_weights(msg, self.rt.topics.weights)
        with self._lock:
            msg, self._pending = self._pending, None
        self.policy_version = apply_weights(
            msg, self.policy, self.policy_version, self.config_hash, self.rt.drops, self.log
        )

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
        policy = self._acting()
        version = self._acting_version(policy)
        self.busy = True
        env = build_env(self.cfg, seed=seed, damage=damage)
        try:
            res = self._run(policy, env, skill, int(req.steps), snap.cov, seed)
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
                f"unavailable: policy version {version} produced non-finite actions or features"
            )
            return reply
        self.evaluations += 1
        reply.achieved.CopyFrom(codec.to_array(res.achieved.astype(np.float32)))
        reply.distance = res.distance
        reply.delta = snap.delta
        reply.ret = res.ret
        reply.violations = res.violations
        reply.steps = res.steps
        reply.policy_version = version
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
            version,
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

    # ---- adaptation jobs ---------------------------------------------------------------------
    def _acting(self) -> Policy | None:
        """The policy of an evaluation: the learner's; before any weights, uniform actions as
        collectors do (None) where φ is provided, and the initial policy (whose encoder gives φ)
        where it is learned, since uniform actions have no φ in skill space there."""
        if self.policy_version > 0 or self.cfg.learned_feature:
            return self.policy
        return None

    @staticmethod
    def _acting_version(policy: Policy | None) -> int:
        """Version of the weights acting (0: none yet, the collector's initial behaviour)."""
        return max(int(policy.version), 0) if policy is not None else 0

    def _run(
        self,
        policy: Policy | None,
        env: ResetFreeEnv,
        skill: np.ndarray,
        steps: int,
        cov: np.ndarray,
        seed: int,
    ) -> SkillRun:
        """One evaluation by the core's rollout and scoring rule (``ursa.eval.rollout``)."""
        return run_skill(
            policy, env, skill, steps, self.feature_key, cov, explore=self.args.explore, seed=seed
        )

    def _job_env(self, run: AdaptRun | None, seed: int) -> ResetFreeEnv:
        """A fresh env: intact (``run`` None) or with the job's damage; rescue off on the A1
        (a rescue would right a fallen robot and credit it with returns it did not earn)."""
        cfg = self.cfg
        if cfg.env == "a1":
            a1 = dataclasses.replace(cfg.a1, rescue=False, damage=None, frozen_joints=())
            if run is not None:
                a1 = dataclasses.replace(a1, damage=run.damage or None, frozen_joints=run.frozen)
            cfg = dataclasses.replace(cfg, a1=a1)
        return build_env(cfg, seed=seed)

    def validate_adapt(self, req: pb.AdaptRequest) -> tuple[ITEParams, str, tuple[int, ...]]:
        """(ITE parameters, damage, frozen joints) of a request; raises ValueError."""
        a = self.args
        if req.damage not in self.damages:
            raise ValueError(
                f"damage {req.damage!r} not one of {', '.join(self.damages[1:])} "
                f"on env {self.cfg.env}"
            )
        frozen = tuple(int(j) for j in req.frozen_joints)
        if frozen and self.cfg.env != "a1":
            raise ValueError(f"frozen_joints need the A1; this run's env is {self.cfg.env}")
        if any(j >= N_JOINTS for j in frozen) or len(set(frozen)) != len(frozen):
            raise ValueError(f"frozen_joints must be distinct indices in 0..{N_JOINTS - 1}")
        if not 1 <= req.budget <= a.max_adapt_budget:
            raise ValueError(f"budget={req.budget} outside 1..{a.max_adapt_budget}")
        if req.skills > a.max_adapt_skills:
            raise ValueError(f"skills={req.skills} above {a.max_adapt_skills}")
        if req.steps > a.max_steps:
            raise ValueError(f"steps={req.steps} above {a.max_steps}")
        limits = {
            "alpha": (req.alpha, 0.0, 1.0),
            "kappa": (req.kappa, -1.0, 100.0),
            "length_scale": (req.length_scale, 0.0, 1000.0),
            "noise": (req.noise, 0.0, 1000.0),
        }
        for name, (v, lo, hi) in limits.items():
            if not (np.isfinite(v) and lo < v <= hi):
                raise ValueError(f"{name}={v!r} outside ({lo:g}, {hi:g}]")
        params = ITEParams(
            alpha=req.alpha,
            kappa=req.kappa,
            budget=int(req.budget),
            length_scale=req.length_scale,
            noise=req.noise,
        )
        damage = "" if req.damage == "none" else req.damage
        return params, damage, tuple(sorted(set(frozen)))

    def start_adapt(self, req: pb.AdaptRequest) -> pb.AdaptJob:
        """Accept a job (the reply carries its id and first state) or refuse it (``error``)."""
        reply = pb.AdaptJob(header=self.rt.header(), evaluator_id=self.args.collector_id)
        try:
            params, damage, frozen = self.validate_adapt(req)
        except ValueError as e:
            reply.error = f"invalid: {e}"
            return reply
        if self.job is not None and self.job.active:
            j = self.job.job
            reply.error = (
                f"busy: job {j.job_id} is {j.state} on evaluator {self.args.collector_id} "
                "(one adaptation at a time per evaluator)"
            )
            return reply
        snap = self._metric()
        if snap is None or snap.size == 0:
            reply.error = "unavailable: no repertoire snapshot yet (the map comes from it)"
            return reply
        if snap.dim != self.skill_dim:
            reply.error = f"unavailable: snapshot dimension {snap.dim} != {self.skill_dim}"
            return reply
        self._load_weights()  # the newest weights, then held for the job
        n = int(req.skills) or self.cfg.repertoire.n_z
        rows = farthest_point_sampling(snap.skills, n, snap.cov)
        skills = np.asarray(snap.skills, np.float64)[rows]
        ids = np.asarray(snap.ids, np.int64)[rows]
        steps = int(req.steps) or self.cfg.collector.skill_period
        seed = int(req.seed) if req.has_seed else self.args.seed + self.evaluations
        key = adapt.map_key(
            kind="evaluator-intact",
            policy_version=self.policy_version,
            config_hash=self.config_hash,
            skills=skills.astype(np.float32),
            ids=ids,
            steps=steps,
            seed=self.args.seed,
            explore=self.args.explore,
            env=self.cfg.env,
            feature=self.cfg.feature,
        )
        accepted = pb.AdaptRequest()
        accepted.CopyFrom(req)
        accepted.damage = damage or "none"
        accepted.ClearField("frozen_joints")
        accepted.frozen_joints.extend(frozen)
        accepted.skills, accepted.steps = len(rows), steps
        accepted.has_seed, accepted.seed = True, seed
        now = time.time()
        job = pb.AdaptJob(
            header=self.rt.header(),
            job_id=uuid.uuid4().hex[:16],
            evaluator_id=self.args.collector_id,
            state=MAPPING,
            request=accepted,
            map_skills=codec.to_array(skills.astype(np.float32)),
            map_ids=codec.to_array(ids),
            map_returns=codec.to_array(np.zeros(0)),
            chosen_skill_id=-1,
            predicted_best_id=-1,
            policy_version=self.policy_version,
            created=now,
            updated=now,
        )
        self.job = AdaptRun(
            job=job,
            skills=skills,
            ids=ids,
            prior=np.zeros(len(rows)),
            params=params,
            damage=damage,
            frozen=frozen,
            steps=steps,
            seed=seed,
            cov=np.asarray(snap.cov, np.float64),
            cache=adapt.map_path(self.args.run.dir, key),
        )
        self.log.info(
            "adaptation job %s: damage %r, frozen %s, %d skills, budget %d, T %d",
            job.job_id,
            damage or "none",
            list(frozen),
            len(rows),
            params.budget,
            steps,
        )
        self._changed(self.job)
        return job

    def _changed(self, run: AdaptRun) -> None:
        """Persist and publish a job's new state."""
        job = run.job
        job.updated = time.time()
        job.header.CopyFrom(self.rt.header())
        self._save_job(job)
        try:
            self.rt.session.put(
                self.rt.topics.adapt_state(self.args.collector_id), codec.encode(job)
            )
        except Exception as e:  # a closed session at shutdown; the file has the state
            self.log.warning("cannot publish job %s: %s", job.job_id, e)

    def _save_job(self, job: pb.AdaptJob) -> None:
        atomic_write(
            self.jobs_dir / f"{job.job_id}.json",
            json_format.MessageToJson(job, preserving_proto_field_name=True),
        )

    def load_job(self, job_id: str) -> pb.AdaptJob | None:
        """A job of this run directory's evaluators, from its file (None: unknown)."""
        if not job_id or not all(c in "0123456789abcdef" for c in job_id):
            return None
        path = self.jobs_dir / f"{job_id}.json"
        try:
            return json_format.Parse(path.read_text(), pb.AdaptJob())
        except (OSError, json_format.ParseError):
            return None

    def _mark_lost(self) -> int:
        """Jobs of this evaluator left unfinished by a previous process: marked ``lost``."""
        lost = 0
        if not self.jobs_dir.is_dir():
            return 0
        for path in sorted(self.jobs_dir.glob("*.json")):
            job = self.load_job(path.stem)
            if job is None or job.evaluator_id != self.args.collector_id:
                continue
            if job.state not in FINAL_STATES:
                was = job.state
                job.state = LOST
                job.stop_reason = (
                    f"lost: evaluator {self.args.collector_id} restarted while the job was {was}"
                )
                job.updated = time.time()
                self._save_job(job)
                lost += 1
                self.log.warning("job %s was %s when the evaluator stopped: lost", job.job_id, was)
        return lost

    def _fail(self, run: AdaptRun, why: str) -> None:
        run.job.state = FAILED
        run.job.stop_reason = f"failed: {why}"
        self.failures += 1
        self.log.warning("adaptation job %s failed: %s", run.job.job_id, why)
        self._changed(run)

    def adapt_step(self) -> bool:
        """One step of the running job (one rollout); False when there is nothing to do."""
        run = self.job
        if run is None or not run.active:
            return False
        try:
            if run.job.state == MAPPING:
                self._map_step(run)
            else:
                self._trial_step(run)
        except Exception as e:  # a failing job must not stop the evaluator
            self.log.exception("adaptation job %s", run.job.job_id)
            self._fail(run, f"{type(e).__name__}: {e}")
        return True

    def _map_step(self, run: AdaptRun) -> None:
        job = run.job
        if job.mapped == 0:
            got = adapt.load_map(run.cache)
            if got is not None and np.array_equal(got[0].ids, run.ids):
                run.prior = np.array(got[0].prior)
                job.mapped, job.map_cached = len(run.ids), True
        if job.mapped < len(run.ids):
            row = int(job.mapped)
            # the map's seeds depend on the row only: the same skills measure the same, so
            # the map is a property of the run and policy, cached across jobs
            env = self._job_env(None, self.args.seed + row)
            try:
                res = self._run(
                    self._acting(), env, run.skills[row], run.steps, run.cov, self.args.seed + row
                )
            finally:
                env.close()
            if not np.isfinite(res.ret):
                self._fail(run, f"intact return of skill {int(run.ids[row])} is not finite")
                return
            run.prior[row] = res.ret
            job.mapped = row + 1
            if job.mapped == len(run.ids):
                adapt.save_map(
                    run.cache,
                    SkillMap(run.skills, run.prior, run.ids),
                    {"policy_version": self.policy_version, "steps": run.steps},
                )
        job.map_returns.CopyFrom(codec.to_array(run.prior[: job.mapped].astype(np.float64)))
        if job.mapped == len(run.ids):
            run.smap = SkillMap(run.skills, run.prior, run.ids)
            job.state = ADAPTING
            self._decide(run)
            if run.active:
                self._changed(run)
        else:
            self._changed(run)

    def _decide(self, run: AdaptRun) -> None:
        """Model, prediction and next row (or the end) after the trials so far."""
        assert run.smap is not None
        d = adapt.decide(run.smap, run.obs, run.params)
        post = d.posterior
        job = run.job
        job.predicted_mean.CopyFrom(codec.to_array(post.mean.astype(np.float64)))
        job.predicted_std.CopyFrom(codec.to_array(post.std.astype(np.float64)))
        job.predicted_best_id = int(run.ids[post.best])
        job.predicted_best_mean = float(post.mean[post.best])
        run.next_row = d.index
        if d.reason is not None:
            job.state = DONE
            job.stop_reason = d.reason
            self.log.info(
                "adaptation job %s done (%s) after %d trials: skill %d, return %.3f",
                job.job_id,
                d.reason,
                len(run.obs),
                job.chosen_skill_id,
                job.chosen_return,
            )
            self._changed(run)

    def _trial_step(self, run: AdaptRun) -> None:
        assert run.smap is not None and run.next_row is not None
        row = run.next_row
        n = len(run.obs)
        seed = run.seed * 100_003 + n
        env = self._job_env(run, seed)
        try:
            res = self._run(self._acting(), env, run.skills[row], run.steps, run.cov, seed)
        finally:
            env.close()
        if not (np.isfinite(res.ret) and np.all(np.isfinite(res.achieved))):
            self._fail(run, f"policy version {self.policy_version} gave non-finite numbers")
            return
        # the model's mean for this skill before the trial (set by the previous _decide)
        prior_mean = float(codec.from_array(run.job.predicted_mean)[row])
        run.obs = run.obs.add(row, res.ret)
        self.adapt_trials += 1
        job = run.job
        if job.chosen_skill_id < 0 or res.ret > job.chosen_return:
            job.chosen_skill_id, job.chosen_return = int(run.ids[row]), float(res.ret)
        self._decide(run)
        job.trials.append(
            pb.AdaptJob.Trial(
                row=row,
                skill_id=int(run.ids[row]),
                skill=codec.to_array(run.skills[row].astype(np.float32)),
                ret=float(res.ret),
                achieved=codec.to_array(res.achieved.astype(np.float32)),
                violations=int(res.violations),
                predicted=prior_mean,
                predicted_best_id=job.predicted_best_id,
                predicted_best_mean=job.predicted_best_mean,
            )
        )
        self._changed(run)

    def job_state(self, job_id: str) -> pb.AdaptJob | None:
        """A job by id ("" the latest of this evaluator), from memory or its file."""
        if self.job is not None and job_id in ("", self.job.job.job_id):
            return self.job.job
        if not job_id:
            return None
        job = self.load_job(job_id)
        return job if job is not None and job.evaluator_id == self.args.collector_id else None

    def _serve_adapt(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        key = self.rt.topics.adapt(self.args.collector_id)
        try:
            req = checked_decode(pb.AdaptRequest, payload, run_id=self.args.run.run_id)
        except codec.BadMessage as e:
            self.rt.drops.add(reason_of(e), key, codec.claimed_sender(payload))
            reply = pb.AdaptJob(header=self.rt.header(), error=f"invalid: {e}")
        else:
            reply = self.start_adapt(req)
        query.reply(key, codec.encode(reply))

    def _serve_adapt_job(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            req = checked_decode(pb.AdaptQuery, payload, run_id=self.args.run.run_id)
        except codec.BadMessage as e:
            self.rt.drops.add(reason_of(e), self.rt.topics.adapt_job(self.args.collector_id))
            return
        job = self.job_state(req.job_id)
        if job is not None:  # a job this evaluator does not hold: no reply (another may)
            job.header.CopyFrom(self.rt.header())
            query.reply(self.rt.topics.adapt_job(self.args.collector_id), codec.encode(job))

    def _poll(self, channel: Any, serve: Callable[[zenoh.Query], None], what: str) -> bool:
        query = channel.try_recv()
        if query is None:
            return False
        try:
            serve(query)
        except Exception:  # a failed reply must not stop the evaluator
            self.log.exception("cannot answer %s query", what)
        finally:
            del query  # finalizes the query (tells the requester no more replies come)
        return True

    def run(self) -> None:
        self._load_weights()
        print(f"EVALUATOR READY {self.args.collector_id}", flush=True)
        last_stats = 0.0
        while not self.rt.stop.is_set():
            served = self._poll(self.adapt_job_queryable, self._serve_adapt_job, "a job-state")
            served = self._poll(self.adapt_queryable, self._serve_adapt, "an adapt") or served
            served = self._poll(self.queryable, self._serve, "an evaluation") or served
            if not (self.adapt_step() or served):
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
                        "adapting": float(self.job is not None and self.job.active),
                        "adapt_trials": self.adapt_trials,
                        "adapt_lost_jobs": self.lost_jobs,
                        **self.last,
                    },
                    labels={"env": self.cfg.env, "feature": self.cfg.feature},
                )
                last_stats = now

    def close(self) -> None:
        for h in [*self.subs, self.queryable, self.adapt_queryable, self.adapt_job_queryable]:
            try:
                h.undeclare()  # type: ignore[attr-defined]
            except Exception:
                pass
        self.rt.close()
