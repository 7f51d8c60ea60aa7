"""The point environment: hand-worked dynamics, reward, cost and safety."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ursa.envs.point import PointConfig, PointEnv

QUIET = PointConfig(noise_std=0.0)


def _at(pos: tuple[float, float], config: PointConfig = QUIET) -> PointEnv:
    env = PointEnv(config, seed=0)
    env._pos = np.asarray(pos, np.float64)
    return env


def test_velocity_command_with_inertia_hand_worked() -> None:
    env = _at((0.5, 0.5))
    obs, *_ = env.step(np.array([1.0, -1.0]))
    # v = 0.5 · 0 + 0.5 · 0.08 · a = (0.04, −0.04)
    np.testing.assert_allclose(obs, [0.54, 0.46, 0.04, -0.04, 1.0, -1.0], rtol=1e-6)
    obs, *_ = env.step(np.array([0.0, 0.0]))
    # v = 0.5 · (0.04, −0.04) = (0.02, −0.02)
    np.testing.assert_allclose(obs[:4], [0.56, 0.44, 0.02, -0.02], rtol=1e-6)


def test_walls_clip_and_stop_the_mass() -> None:
    env = _at((0.99, 0.0))
    obs, *_ = env.step(np.array([1.0, 0.0]))
    assert obs[0] == pytest.approx(1.0)
    assert obs[2] == 0.0


def test_actions_are_clipped() -> None:
    env = _at((0.5, 0.5))
    obs, *_ = env.step(np.array([5.0, -5.0]))
    np.testing.assert_allclose(obs[4:], [1.0, -1.0])


def test_non_finite_actions_do_not_corrupt_the_state() -> None:
    env = _at((0.5, 0.5))
    obs, r, _, _, info = env.step(np.array([np.nan, np.inf]))
    assert np.all(np.isfinite(obs)) and np.isfinite(r) and np.isfinite(info["cost"])
    np.testing.assert_allclose(obs[4:], [0.0, 1.0])


def test_reward_hand_worked() -> None:
    env = _at((0.8, 0.8))
    _, r, *_ = env.step(np.zeros(2))
    assert r == pytest.approx(1.0)
    env = _at((-0.8, -0.8))
    _, r, _, _, info = env.step(np.array([1.0, 0.0]))
    # the point moves to (−0.76, −0.8): distance to the goal √(1.56² + 1.6²)
    d = np.hypot(1.56, 1.6)
    assert info["reward_terms"]["goal"] == pytest.approx(1.0 - d / (2 * np.sqrt(2)))
    assert r == pytest.approx(1.0 - d / (2 * np.sqrt(2)) - 0.01)


@pytest.mark.parametrize(
    ("pos", "cost", "safe"),
    [
        ((0.0, 0.1), 0.35, False),  # inside the disc: the signed distance + the jump 0.1
        ((0.0, 0.33), 0.12, False),
        ((0.0, 0.37), -0.02, True),  # just outside: the signed distance, negative
        ((0.0, 0.9), -0.05, True),  # far away: the floor
    ],
)
def test_cost_and_safety(pos: tuple[float, float], cost: float, safe: bool) -> None:
    env = _at(pos)
    _, _, _, _, info = env.step(np.zeros(2))
    assert info["cost"] == pytest.approx(cost, abs=1e-9)
    assert info["safe"] is safe
    assert (info["cost"] <= 0.0) == safe  # the paper's c(s) ≤ 0 ⇔ s safe
    np.testing.assert_array_equal(info["features"]["position"], np.asarray(pos, np.float32))


def test_cost_floor_and_jump_are_configurable() -> None:
    env = _at((0.0, 0.9), dataclasses.replace(QUIET, cost_floor=-1.0))
    _, _, _, _, info = env.step(np.zeros(2))
    assert info["cost"] == pytest.approx(0.35 - 0.9)
    env = _at((0.0, 0.3), dataclasses.replace(QUIET, cost_jump=0.0))
    _, _, _, _, info = env.step(np.zeros(2))
    assert info["cost"] == pytest.approx(0.05)


def test_reset_free_and_safe_start() -> None:
    for seed in range(20):
        env = PointEnv(seed=seed)
        obs, _ = env.reset()
        assert np.linalg.norm(obs[:2]) >= 0.35
        for _ in range(30):
            env.step(np.ones(2))
        before, _ = env.reset()
        np.testing.assert_array_equal(before, env._obs())
        assert before[0] > 0.9  # pushed into the wall, not moved back
