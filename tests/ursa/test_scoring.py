"""The one scoring rule of skill execution (ursa.scoring): hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest

from ursa import scoring


def test_settle_steps_is_a_fifth_of_the_skill_and_leaves_a_step() -> None:
    assert scoring.settle_steps(250) == 50
    assert scoring.settle_steps(100) == 20
    assert scoring.settle_steps(3) == 0
    assert scoring.settle_steps(1) == 0
    with pytest.raises(ValueError):
        scoring.settle_steps(0)


def test_achieved_skill_averages_after_the_settle_period() -> None:
    # transit 0 -> 1 in the first 2 steps, then at 1: the settled mean is 1, the raw mean less
    phi = np.array([[0.0], [0.5], [1.0], [1.0], [1.0]])
    assert scoring.achieved_skill(phi, 2)[0] == pytest.approx(1.0)
    assert scoring.achieved_skill(phi, 0)[0] == pytest.approx(3.5 / 5)
    with pytest.raises(ValueError):
        scoring.achieved_skill(phi, 5)


def test_skill_distance_is_mahalanobis_in_the_metric_of_delta() -> None:
    cov = np.diag([4.0, 0.25])  # std 2 and 0.5
    d = scoring.skill_distance(np.array([[2.0, 0.0], [0.0, 1.0]]), np.zeros((2, 2)), cov)
    np.testing.assert_allclose(d, [1.0, 2.0], rtol=1e-6)


def test_the_rule_is_the_stochastic_policy() -> None:
    # Definition 2.1: a skill is E_π[φ] of the skill-conditioned policy, which is what the
    # actor is trained for; the learning tests, ursa eval and the evaluator all score that
    assert scoring.EXPLORE is True
