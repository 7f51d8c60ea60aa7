"""Execute skills with a policy in the real env and record what happened: the one rollout of
every evaluation (the learning tests through ``ursa.serial.evaluate_skills``, ``ursa eval``, the
evaluator service through :func:`run_skill`).

:func:`execute_skills` runs K skills, T steps each, one after the other in one reset-free env (as
a collector executes them), or each from a freshly righted robot (``restand``, used by the damage
evaluation so that trials are independent). It acts and scores by the rule of
:mod:`ursa.scoring` (policy mode, settle period), starts a new recurrent state at a rescue (as
collectors do), and records per skill the mean of chosen ``info["features"]`` entries, the mean
of φ (the skill actually achieved), the return, the violation rate and optionally the
observations and actions.

Also here: farthest-point sampling of the N_z most distinct skills of a repertoire in the
Mahalanobis metric of δ.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm.auto import tqdm

from ursa import kde, scoring
from ursa.envs.base import ResetFreeEnv
from ursa.policy import Policy, PolicyCarry


@dataclass
class Rollouts:
    """What K skills did over T steps each (arrays indexed by skill)."""

    skills: np.ndarray
    """Targets (K, D) (D = 0 for a policy without skills)."""
    means: dict[str, np.ndarray]
    """Mean of each recorded ``info["features"]`` entry over the measured steps, (K, F)."""
    achieved: np.ndarray | None
    """Mean φ over the measured steps (K, D); None without skills or without ``phi_key``."""
    returns: np.ndarray
    """Undiscounted return over the T steps (K,)."""
    violation_rate: np.ndarray
    """Fraction of unsafe steps (K,)."""
    abs_error: dict[str, np.ndarray] = field(default_factory=dict)
    """Mean over the measured steps of |feature_t − skill| per dimension, (K, D), for the
    feature keys that are φ itself (a provided feature)."""
    obs: np.ndarray | None = None
    """Observations (K, T, obs_dim) after each step, when asked for."""
    actions: np.ndarray | None = None
    """Actions (K, T, act_dim) as sent to the env, when asked for."""
    rescues: int = 0
    """Rescue teleports during the rollouts (each starts a new recurrent state)."""
    nonfinite_actions: int = 0
    """Actions with a NaN or inf entry (a diverged policy; the env receives them as they are)."""
    steps: int = 0
    settle: int = 0

    @property
    def unsafe_steps(self) -> np.ndarray:
        """Unsafe steps of each skill (K,) int."""
        return np.rint(self.violation_rate * self.steps).astype(np.int64)


def farthest_point_sampling(
    points: np.ndarray, k: int, cov: np.ndarray | None = None, start: int | None = None
) -> np.ndarray:
    """Indices (min(k, N),) of ``k`` points of ``points`` (N, D) picked greedily, each the
    farthest (Mahalanobis, Σ = ``cov``; Euclidean when None) from those already picked.

    The first is ``start``, or by default the point farthest from the mean (an extreme point,
    so that the boundary of the repertoire is covered first). Deterministic (ties: lowest index).
    """
    pts = np.asarray(points, np.float64)
    n = len(pts)
    k = min(int(k), n)
    if k <= 0:
        return np.zeros(0, np.int64)
    if cov is not None:
        w = kde.whitening_matrix(kde.regularize_cov(np.asarray(cov, np.float64)))
        pts = pts @ w.T
    if start is None:
        start = int(np.argmax(np.linalg.norm(pts - pts.mean(0), axis=1)))
    chosen = [int(start)]
    dist = np.linalg.norm(pts - pts[start], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(pts - pts[nxt], axis=1))
    return np.asarray(chosen, np.int64)


def stand_up(env: ResetFreeEnv) -> np.ndarray | None:
    """Right an A1 where it is (standing pose, standing height, zero velocity, same heading),
    as the env's rescue does; returns the observation (None for envs without ``place``)."""
    place = getattr(env, "place", None)
    if place is None or not hasattr(env, "standing_height"):
        return None
    cfg = env.config  # type: ignore[attr-defined]
    pos, orn = env.base_pose()  # type: ignore[attr-defined]
    x, y, z, w = (float(v) for v in orn)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    quat = (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))
    obs: np.ndarray = place(
        position=(float(pos[0]), float(pos[1]), float(env.standing_height)),  # type: ignore[attr-defined]
        orientation=quat,
        linear_velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        joint_angles=np.tile(np.asarray(cfg.standing_pose, np.float64), 4),
    )
    return obs


def execute_skills(
    policy: Policy | None,
    env: ResetFreeEnv,
    skills: np.ndarray,
    steps: int,
    record: Sequence[str] = (),
    phi_key: str | None = None,
    tracking: bool = False,
    settle: int | None = None,
    explore: bool = scoring.EXPLORE,
    keep_obs: bool = False,
    keep_actions: bool = False,
    restand: bool = False,
    seed: int = 0,
    progress: bool = True,
    desc: str = "skills",
    encode: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Rollouts:
    """Run each skill of ``skills`` (K, D) for ``steps`` env steps.

    policy: None acts uniformly at random (a collector's prefill; φ is then the ``phi_key``
    feature itself, or ``encode`` (n, F) -> (n, D) of it for a learned φ); a policy without
    skills (``daydreamer``) ignores the skill (pass ``np.zeros((K, 0))``). record:
    ``info["features"]`` keys whose mean is kept. phi_key: the key φ is computed from (the
    VAE input or the provided feature); None: no φ.
    tracking: ``phi_key`` is φ itself (a provided feature): also keep the per-step absolute
    tracking error. settle: the first steps of each skill are executed but not measured
    (default: the scoring rule's, :func:`ursa.scoring.settle_steps`). explore: sampled actions
    (the scoring rule's default) or the policy's mode.
    restand: right the robot (A1) and restart the policy's memory before each skill, so that
    skills are independent trials; otherwise the env runs on without resets and the policy
    keeps its carry across skills (a collector's behaviour). A rescue (``info["rescued"]``)
    starts a new carry either way: the robot was teleported. keep_obs, keep_actions: record the
    observation after each step and the action sent (replay convention). seed: the random
    actions, the policy's action noise and its RSSM latents all come from it.
    """
    skills = np.asarray(skills, np.float64)
    if skills.ndim != 2:
        raise ValueError("skills must be (K, D)")
    settle = scoring.settle_steps(steps) if settle is None else settle
    if not 0 <= settle < steps:
        raise ValueError("need 0 <= settle < steps")
    k = len(skills)
    rng = np.random.default_rng(seed)
    if policy is not None:
        # the RSSM latents come from the policy's own generator: reseeded, a call's result
        # depends on its seed only, not on what the same policy executed before
        policy.latent_rng = np.random.default_rng([seed, 1])
    keys = list(dict.fromkeys([*record, *([phi_key] if phi_key else [])]))
    sums = {key: np.zeros((k, int(env.feature_dims[key]))) for key in keys}
    err = np.zeros_like(skills) if tracking and phi_key else None
    achieved = np.zeros_like(skills) if phi_key and skills.shape[1] else None
    returns = np.zeros(k)
    unsafe = np.zeros(k)
    nonfinite = 0
    obs_rec = np.zeros((k, steps, env.obs_dim), np.float32) if keep_obs else None
    act_rec = np.zeros((k, steps, env.act_dim), np.float32) if keep_actions else None
    rescues = 0
    measured = steps - settle
    obs, _ = env.reset()
    carry: PolicyCarry | None = policy.initial_carry() if policy is not None else None
    bar = tqdm(total=k * steps, desc=desc, unit="step", disable=not progress, leave=False)
    try:
        for i, z in enumerate(skills):
            if restand:
                stood = stand_up(env)
                if stood is not None:
                    obs = stood
                if policy is not None:
                    carry = policy.initial_carry()
            phi_in = []
            for t in range(steps):
                if policy is None or carry is None:
                    action = rng.uniform(-1.0, 1.0, env.act_dim)
                else:
                    action, carry = policy.act(
                        carry, obs, z if len(z) else None, explore=explore, rng=rng
                    )
                nonfinite += 0 if np.all(np.isfinite(action)) else 1
                obs, reward, _, _, info = env.step(action)
                if info.get("rescued"):
                    rescues += 1
                    if policy is not None:
                        carry = policy.initial_carry()
                returns[i] += float(reward)
                unsafe[i] += 0.0 if info["safe"] else 1.0
                if obs_rec is not None:
                    obs_rec[i, t] = obs
                if act_rec is not None:
                    act_rec[i, t] = action
                if t < settle:
                    continue
                feats = info["features"]
                for key in keys:
                    sums[key][i] += np.asarray(feats[key], np.float64)
                if phi_key is not None and achieved is not None:
                    phi_in.append(np.asarray(feats[phi_key], np.float64))
                if err is not None and phi_key is not None:
                    err[i] += np.abs(np.asarray(feats[phi_key], np.float64) - z)
            if achieved is not None and phi_in:
                x = np.stack(phi_in)
                phi = policy.features if policy is not None else encode
                achieved[i] = (phi(x) if phi is not None else x).mean(0)
            bar.update(steps)
    finally:
        bar.close()
    means = {key: v / measured for key, v in sums.items()}
    out = Rollouts(
        skills=skills,
        means=means,
        achieved=achieved,
        returns=returns,
        violation_rate=unsafe / steps,
        obs=obs_rec,
        actions=act_rec,
        rescues=rescues,
        steps=steps,
        settle=settle,
        nonfinite_actions=nonfinite,
    )
    if err is not None and phi_key is not None:
        out.abs_error[phi_key] = err / measured
    return out


@dataclass(frozen=True)
class SkillRun:
    """What one skill achieved in one evaluation (:func:`run_skill`)."""

    achieved: np.ndarray
    """Mean φ over the steps after the settle period (D,)."""
    distance: float
    """Mahalanobis distance of ``achieved`` to the target, Σ = the metric covariance."""
    ret: float
    """Undiscounted return over every step."""
    violations: int
    """Unsafe steps."""
    steps: int
    elapsed_s: float


def score_skills(
    policy: Policy | None,
    env: ResetFreeEnv,
    skills: np.ndarray,
    steps: int,
    phi_key: str,
    metric_cov: np.ndarray,
    explore: bool = scoring.EXPLORE,
    seed: int = 0,
    settle: int | None = None,
    record: bool = False,
    encode: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[Rollouts, np.ndarray]:
    """:func:`execute_skills` of ``skills`` (K, D), reset-free, and the distance (K,) of each
    achieved skill to its target in the metric Σ = ``metric_cov`` (the scoring rule of
    :mod:`ursa.scoring`). ``record`` keeps the observations and actions; ``encode``: φ of
    random actions (``policy`` None) on a learned feature."""
    skills = np.asarray(skills, np.float64)
    r = execute_skills(
        policy,
        env,
        skills,
        steps,
        phi_key=phi_key,
        settle=settle,
        explore=explore,
        keep_obs=record,
        keep_actions=record,
        seed=seed,
        progress=False,
        encode=encode,
    )
    assert r.achieved is not None
    return r, scoring.skill_distance(r.achieved, skills, metric_cov)


def run_skill(
    policy: Policy | None,
    env: ResetFreeEnv,
    skill: np.ndarray,
    steps: int,
    phi_key: str,
    metric_cov: np.ndarray,
    explore: bool = scoring.EXPLORE,
    seed: int = 0,
    settle: int | None = None,
) -> SkillRun:
    """One skill (D,) for ``steps`` steps from the env's state, from a fresh carry
    (:func:`score_skills` with K = 1): one evaluation of the evaluator service."""
    t0 = time.perf_counter()
    z = np.asarray(skill, np.float64)[None]
    r, distance = score_skills(policy, env, z, steps, phi_key, metric_cov, explore, seed, settle)
    assert r.achieved is not None
    return SkillRun(
        achieved=r.achieved[0],
        distance=float(distance[0]),
        ret=float(r.returns[0]),
        violations=int(r.unsafe_steps[0]),
        steps=steps,
        elapsed_s=time.perf_counter() - t0,
    )


def skill_distance(achieved: np.ndarray, skills: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Mahalanobis distance ‖achieved − z‖_Σ (K,) in the metric of δ (:mod:`ursa.scoring`)."""
    return scoring.skill_distance(achieved, skills, cov)


def trials_on(
    env: ResetFreeEnv,
    policy: Policy | None,
    skills: np.ndarray,
    steps: int,
    explore: bool = scoring.EXPLORE,
    seed: int = 0,
    progress: bool = True,
    desc: str = "skills",
) -> Rollouts:
    """Each skill of ``skills`` (K, D) as an independent trial (:func:`execute_skills` with
    ``restand``) on ``env``, which is closed afterwards: a damage scenario's evaluation."""
    try:
        return execute_skills(
            policy,
            env,
            skills,
            steps,
            restand=True,
            explore=explore,
            seed=seed,
            progress=progress,
            desc=desc,
        )
    finally:
        env.close()
