"""A single-process URSA loop (Alg. 1 and 2 interleaved): the reference behaviour of the
services, and what the learning tests run.

Each env step (``ursa.acting``, a collector's acting loop): a new KDE skill every
``skill_period`` steps; act with the current policy (uniformly random actions during the
prefill); record the transition; every ``chunk_len`` steps the chunk goes to the replay and the
features of its safe steps to the repertoire. After
the prefill the learner trains whenever ``updates · B · T < train_ratio · env steps`` (the
replay ratio), and the policy receives the learner's weights every ``sync_every`` updates. With
a learned φ the repertoire re-encodes its inputs whenever the learner publishes an encoder.

``evaluate_skills`` runs a policy on a list of skills in the real env (reset-free: one skill
after the other, T steps each) and reports what each achieved (the evaluation rollout of
``ursa.eval.rollout``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ursa import scoring
from ursa.acting import Acting, ActingConfig, Chunk
from ursa.bounds import Box
from ursa.envs.base import ResetFreeEnv
from ursa.eval.rollout import score_skills
from ursa.learner import Learner, SkillSnapshot
from ursa.learner_config import LearnerConfig
from ursa.policy import Policy
from ursa.repertoire import Repertoire, RepertoireConfig
from ursa.replay import Replay
from ursa.safety_floor import ema_rate


@dataclass(frozen=True)
class SerialConfig:
    """Settings of the single-process loop."""

    feature: str = "position"
    """Key of ``info["features"]`` recorded as the replay's ``features``: φ itself in
    ``ursa-supervised``, the VAE input in ``ursa`` (e.g. ``vae_input``)."""
    prefill: int = 2000
    """Env steps of uniformly random actions before the first update."""
    random_scale: float = 1.0
    """The prefill's actions are uniform in [−s, s]^A (``CollectorConfig.random_scale``)."""
    skill_period: int = 250
    """T: env steps between two skills drawn from the repertoire's KDE."""
    chunk_len: int = 50
    """Records per replay chunk (as a collector would send them)."""
    archive_window: int = 1
    """The repertoire admits the mean feature of each block of this many safe steps
    (``CollectorConfig.archive_window``)."""
    sync_every: int = 20
    """Updates between two policy weight syncs."""
    snapshot_every: int = 10
    """Updates between two repertoire snapshots given to the learner."""
    replay_capacity: int = 1_000_000
    """Records the replay keeps."""
    repertoire_size: int = 5000
    """N_R."""
    n_z: int = 100
    """N_z (sets δ)."""
    seed: int = 0
    """Seed of the loop's generator (skills, random actions, replay sampling)."""


@dataclass
class EvalResult:
    """What each of K skills achieved in the real env."""

    skills: np.ndarray
    """Target skills (K, D)."""
    achieved: np.ndarray
    """Mean feature over the T steps of each skill (K, D)."""
    distance: np.ndarray
    """Mahalanobis distance ‖achieved − z‖_Σ (K,)."""
    returns: np.ndarray
    """Undiscounted sum of rewards over the T steps (K,)."""
    violation_rate: np.ndarray
    """Fraction of unsafe steps (K,)."""
    obs: np.ndarray | None = None
    """Observations (K, T, obs_dim) after each step, when recorded."""
    actions: np.ndarray | None = None
    """Actions (K, T, act_dim), when recorded."""

    def within(self, delta: float) -> np.ndarray:
        """Which skills were achieved within δ (K,) bool."""
        return self.distance <= delta


def evaluate_skills(
    policy: Policy | None,
    env: ResetFreeEnv,
    skills: np.ndarray,
    steps: int,
    metric_cov: np.ndarray,
    feature: str = "position",
    explore: bool = scoring.EXPLORE,
    seed: int = 0,
    record: bool = False,
    settle: int | None = None,
    encode: Callable[[np.ndarray], np.ndarray] | None = None,
) -> EvalResult:
    """Run each skill (K, D) for ``steps`` env steps in turn, without resets, and score it by
    the rule of :mod:`ursa.scoring`: :func:`ursa.eval.rollout.score_skills` (the one
    evaluation rollout, with the distance of each achieved skill to its target).

    ``policy`` None acts uniformly at random (φ = the provided feature ``feature``, or
    ``encode`` of it: a learned φ, e.g. the trained policy's ``features``); otherwise
    φ is the policy's (its VAE encoder in ``ursa`` mode) applied to
    ``info["features"][feature]``; distances use Σ = ``metric_cov``, the metric of δ. ``record``
    keeps the observations and actions (replay convention: the observation after each action).
    """
    r, distance = score_skills(
        policy, env, skills, steps, feature, metric_cov, explore, seed, settle, record, encode
    )
    assert r.achieved is not None
    return EvalResult(r.skills, r.achieved, distance, r.returns, r.violation_rate, r.obs, r.actions)


@dataclass
class SerialLoop:
    """Collector + repertoire + replay + learner in one process; call :meth:`run`."""

    env: ResetFreeEnv
    learner_config: LearnerConfig
    config: SerialConfig = field(default_factory=SerialConfig)
    stream_id: str = "serial-0"
    skill_box: Box | None = None
    """The skill box of the feature function (``ursa.bounds``): the repertoire admits no skill
    outside it and truncates its KDE draws to it; None: no bounds."""

    def __post_init__(self) -> None:
        c, lc = self.config, self.learner_config
        self.feat_in_dim = int(self.env.feature_dims.get(c.feature, 0))
        if lc.uses_skills and self.feat_in_dim == 0:
            raise ValueError(f"env has no feature {c.feature!r}")
        self.learner = Learner(lc, self.env.obs_dim, self.env.act_dim, max(self.feat_in_dim, 1))
        d = self.learner.skill_dim
        self.policy = Policy(
            lc, self.env.obs_dim, self.env.act_dim, d, max(self.feat_in_dim, 1), seed=c.seed + 1
        )
        self.policy.load_weights_bytes(self.learner.policy_weights_bytes())
        self.repertoire: Repertoire | None = None
        if lc.uses_skills:
            self.repertoire = Repertoire(
                RepertoireConfig(
                    size=c.repertoire_size,
                    dim=d,
                    n_z=c.n_z,
                    input_dim=self.feat_in_dim if lc.mode == "ursa" else None,
                ),
                bounds=self.skill_box,
            )
        self.replay = Replay(c.replay_capacity)
        self.rng = np.random.default_rng(c.seed)
        self.acting = Acting(
            self.env,
            self.policy,
            ActingConfig(
                feature=c.feature,
                skill_period=c.skill_period,
                chunk_len=c.chunk_len,
                random_scale=c.random_scale,
            ),
            self.rng,
        )
        self.unsafe_steps = 0
        self.violation_rate: float | None = None
        """Exponential average of the stored steps' violation (``ursa.safety_floor``)."""
        self.history: list[dict[str, float]] = []
        self._snapshot: SkillSnapshot | None = None

    @property
    def env_steps(self) -> int:
        """Env steps collected."""
        return self.acting.step_count

    # --- collection ----------------------------------------------------------------------------

    def _new_skill(self) -> np.ndarray:
        rep = self.repertoire
        if rep is None:
            return np.zeros(0)
        if len(rep) < 2:
            return np.zeros(rep.config.dim)
        return rep.sample(1, self.rng)[0]

    def _store(self, chunk: Chunk) -> None:
        """A finished chunk into the replay, its safe features into the repertoire."""
        self.replay.add(self.stream_id, chunk.data, chunk.first_step)
        if len(chunk.data["safe"]):
            self.violation_rate = ema_rate(
                self.violation_rate, ~chunk.data["safe"], self.learner_config.lambda2_floor_window
            )
        rep = self.repertoire
        x = chunk.archive_features(self.config.archive_window).astype(np.float64)
        if rep is not None and len(x):
            if self.learner_config.mode == "ursa":
                rep.commit_many(self.policy.features(x), x)
            else:
                rep.commit_many(x)

    def _flush(self) -> None:
        for chunk in self.acting.flush():
            self._store(chunk)

    def collect(self, steps: int) -> None:
        """Step the env ``steps`` times with the current policy (random during the prefill)."""
        for _ in range(steps):
            if self.acting.skill_due():
                self.acting.skill = self._new_skill()
            res = self.acting.step(random=self.env_steps < self.config.prefill)
            for chunk in res.chunks:
                self._store(chunk)
            self.unsafe_steps += 0 if res.info["safe"] else 1

    # --- training ------------------------------------------------------------------------------

    def snapshot(self) -> SkillSnapshot | None:
        """The learner's current view of the repertoire (None without skills)."""
        if self.repertoire is None:
            return None
        return SkillSnapshot.from_repertoire(self.repertoire)

    def train(self, max_updates: int | None = None) -> int:
        """Run the updates the replay ratio allows now (at most ``max_updates``); returns how
        many ran."""
        c, lc = self.config, self.learner_config
        if self.env_steps < c.prefill or len(self.replay) < lc.seq_len:
            return 0
        per_update = lc.batch_size * lc.seq_len
        done = 0
        while self.learner.updates * per_update < lc.train_ratio * self.replay.inserted:
            if max_updates is not None and done >= max_updates:
                break
            if self._snapshot is None or self.learner.updates % c.snapshot_every == 0:
                self._snapshot = self.snapshot()
            batch = self.replay.sample(lc.batch_size, lc.seq_len, self.rng, lc.replay_unsafe)
            metrics = self.learner.train_step(batch, self._snapshot, self.violation_rate)
            metrics["env_steps"] = float(self.env_steps)
            self.history.append(metrics)
            done += 1
            rep = self.repertoire
            if (
                rep is not None
                and lc.mode == "ursa"
                and rep.encoder_version != self.learner.vae_version
            ):
                rep.reencode(self.learner.encode, self.learner.vae_version)
                self._snapshot = None
                self.sync_policy()
            if self.learner.updates % c.sync_every == 0:
                self.sync_policy()
        return done

    def sync_policy(self) -> None:
        """Ship the learner's weights to the policy (as a collector would receive them)."""
        self.policy.load_weights_bytes(self.learner.policy_weights_bytes())

    def run(
        self,
        env_steps: int,
        max_seconds: float | None = None,
        callback: Callable[[SerialLoop], None] | None = None,
        callback_every: int = 1000,
    ) -> SerialLoop:
        """Collect ``env_steps`` more env steps, training as the replay ratio allows, or stop
        after ``max_seconds``. ``callback(loop)`` runs every ``callback_every`` env steps."""
        start = time.perf_counter()
        target = self.env_steps + env_steps
        step = min(self.config.chunk_len, self.config.skill_period)
        while self.env_steps < target:
            self.collect(min(step, target - self.env_steps))
            self.train()
            if callback is not None and self.env_steps % callback_every < step:
                callback(self)
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                break
        self._flush()
        self.sync_policy()
        return self
