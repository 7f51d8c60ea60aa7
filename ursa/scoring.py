"""How the execution of a skill is scored, in one place: the learning tests, ``ursa eval`` and
the evaluator service all call these.

A skill z is executed for T env steps, one after the other without resets. What it achieved
is the mean of φ over the steps after a *settle* period: the first ``SETTLE_FRACTION`` · T steps
carry the robot from where the previous skill left it (reset-free, there is no start state of
the skill's own), and scoring them would measure the transit, not the skill. The policy acts
as the stochastic π_z (``EXPLORE`` True): a skill is the expected feature of the
skill-conditioned policy (the paper's Definition 2.1), the quantity the actor and its skill
constraint are trained on; measured on the point recipe over two seeds, its mode (tanh(mean)
actions) executed 5–15 points fewer skills within δ (docs/learner.md). The distance is the
Mahalanobis distance in the metric of δ (Σ = the repertoire's KDE covariance), and a skill is
executed when the distance is ≤ δ.
"""

from __future__ import annotations

import numpy as np

from ursa import kde

EXPLORE = True
"""Score the stochastic policy π_z (sampled actions), not its mode."""
SETTLE_FRACTION = 0.2
"""Fraction of a skill's steps executed but not measured (transit from the previous skill)."""


def settle_steps(steps: int) -> int:
    """Steps (of ``steps``) executed before a skill's measurement starts."""
    if steps < 1:
        raise ValueError("steps must be ≥ 1")
    return min(int(SETTLE_FRACTION * steps), steps - 1)


def skill_distance(achieved: np.ndarray, skills: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """‖achieved − z‖_Σ (...) of achieved and target skills (..., D), Σ = ``cov`` (D, D), the
    metric of δ (regularised when singular)."""
    w = kde.whitening_matrix(kde.regularize_cov(np.asarray(cov, np.float64)))
    diff = (np.asarray(achieved, np.float64) - np.asarray(skills, np.float64)) @ w.T
    return np.asarray(np.linalg.norm(diff, axis=-1))


def achieved_skill(phi: np.ndarray, settle: int) -> np.ndarray:
    """Mean (..., D) of φ (..., T, D) over the steps from ``settle`` on."""
    phi = np.asarray(phi, np.float64)
    if not 0 <= settle < phi.shape[-2]:
        raise ValueError(f"need 0 <= settle < T, got settle {settle}, T {phi.shape[-2]}")
    return np.asarray(phi[..., settle:, :].mean(-2))
