"""One evaluation: run a fixed skill for ``steps`` control steps and measure what it achieved.

Pure (no bus): the evaluator service and the tests call :func:`run_skill`. The skill is scored
by the one rule of :mod:`ursa.scoring`: the achieved skill is the mean of φ over the steps after
the settle period (φ = the policy's encoder applied to ``info["features"][key]`` with a learned
φ, the provided feature itself otherwise), its distance to the target is Mahalanobis in the
repertoire's metric (Σ of the latest snapshot, the metric of δ), exactly as
``ursa.serial.evaluate_skills`` measures it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from services.evaluator.acting import Acting
from ursa import scoring
from ursa.envs.base import ResetFreeEnv


@dataclass(frozen=True)
class RunResult:
    """What one skill achieved."""

    achieved: np.ndarray
    """Mean φ over the run after the settle period (D,)."""
    distance: float
    """Mahalanobis distance of ``achieved`` to the target, Σ = the metric covariance."""
    ret: float
    """Undiscounted return."""
    violations: int
    """Unsafe steps."""
    steps: int
    elapsed_s: float


def run_skill(
    env: ResetFreeEnv,
    acting: Acting,
    skill: np.ndarray,
    steps: int,
    feature_key: str,
    metric_cov: np.ndarray,
    settle: int | None = None,
) -> RunResult:
    """Act ``steps`` times with ``skill`` (D,) fixed from the env's current state; the first
    ``settle`` steps (default :func:`ursa.scoring.settle_steps`) are not measured."""
    t0 = time.perf_counter()
    skill = np.asarray(skill, np.float64)
    obs, _ = env.reset()
    acting.begin()
    inputs = []
    ret = 0.0
    violations = 0
    for _ in range(steps):
        action = acting.act(obs, skill)
        obs, reward, _, _, info = env.step(action)
        inputs.append(np.asarray(info["features"][feature_key], np.float64))
        ret += float(reward)
        violations += 0 if info["safe"] else 1
    phi = np.asarray(acting.features(np.stack(inputs)), np.float64)
    settle = scoring.settle_steps(steps) if settle is None else settle
    achieved = scoring.achieved_skill(phi, settle)
    distance = float(scoring.skill_distance(achieved, skill, metric_cov))
    return RunResult(achieved, distance, ret, violations, steps, time.perf_counter() - t0)
