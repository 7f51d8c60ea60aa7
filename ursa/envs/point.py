"""A tiny reset-free environment with the A1's interface, for fast learning tests.

A point mass moves in the square arena [-1, 1]^2 under velocity commands. A disc in the middle
of the arena is unsafe (a stand-in for "fallen over"): the cost is positive inside it. The
reward prefers one corner, so a reward-only agent (the ``daydreamer`` mode) covers little of the
arena, while a skill-conditioned agent can be asked to stay anywhere safe. The feature
function is the position, so a skill z is the mean position over T steps.

Observation layout (6,): position (2), velocity (2), previous action (2).
Action (2,): velocity command in [-1, 1]^2, scaled by ``max_speed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PointConfig:
    """Settings of the point environment."""

    max_speed: float = 0.08
    """Distance moved per step at full command (arena units)."""
    inertia: float = 0.5
    """Fraction of the previous velocity kept each step (0: pure velocity control)."""
    noise_std: float = 0.002
    """Standard deviation of the position noise added each step."""
    unsafe_radius: float = 0.35
    """Radius of the unsafe disc centred at the origin."""
    cost_floor: float = -0.05
    """Lowest cost of a safe state (cost = max(unsafe_radius − ‖p‖, cost_floor)). Bounded
    below so that, in the discounted cost critic, time far from the disc cannot offset time
    spent inside it (the A1's cost is bounded the same way)."""
    cost_jump: float = 0.1
    """Cost added inside the disc (cost = unsafe_radius − ‖p‖ + cost_jump there), so that
    hovering on the disc's edge, half the steps in and half out, has a positive discounted
    cost; safe ⇔ cost ≤ 0 still holds."""
    goal: tuple[float, float] = (0.8, 0.8)
    """Where the reward is highest."""
    action_penalty: float = 0.01
    """Weight of the squared-action penalty in the reward."""


class PointEnv:
    """Reset-free point mass; see the module docstring. Implements ``ResetFreeEnv``."""

    obs_dim = 6
    act_dim = 2
    feature_dims: dict[str, int] = {"position": 2}  # noqa: RUF012 - read-only, per class

    def __init__(self, config: PointConfig | None = None, seed: int = 0) -> None:
        self.config = config or PointConfig()
        self._rng = np.random.default_rng(seed)
        self._pos = self._rng.uniform(-0.9, 0.9, size=2)
        # start outside the unsafe disc so that the first state is safe
        while np.linalg.norm(self._pos) < self.config.unsafe_radius + 0.05:
            self._pos = self._rng.uniform(-0.9, 0.9, size=2)
        self._vel = np.zeros(2)
        self._prev_action = np.zeros(2)
        self._steps = 0
        self._reset_calls = 0

    def _obs(self) -> np.ndarray:
        return np.concatenate([self._pos, self._vel, self._prev_action]).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Return the current observation; the state is never reset (see ``ursa.envs.base``)."""
        self._reset_calls += 1
        return self._obs(), {"reset_calls": self._reset_calls - 1, "step": self._steps}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        c = self.config
        # NaN becomes 0 (as on the A1): one NaN would corrupt a state that is never reset
        a = np.clip(np.nan_to_num(np.asarray(action, dtype=np.float64).reshape(2)), -1.0, 1.0)
        self._vel = c.inertia * self._vel + (1.0 - c.inertia) * c.max_speed * a
        pos = self._pos + self._vel + self._rng.normal(0.0, c.noise_std, size=2)
        clipped = np.clip(pos, -1.0, 1.0)
        self._vel = np.where(clipped != pos, 0.0, self._vel)  # walls stop the mass
        self._pos = clipped
        self._prev_action = a
        self._steps += 1

        dist_goal = float(np.linalg.norm(self._pos - np.asarray(c.goal)))
        r_goal = 1.0 - dist_goal / (2.0 * np.sqrt(2.0))
        r_action = -c.action_penalty * float(a @ a)
        reward = r_goal + r_action
        signed = c.unsafe_radius - float(np.linalg.norm(self._pos))
        safe = signed <= 0.0
        cost = max(signed, c.cost_floor) if safe else signed + c.cost_jump
        info: dict[str, Any] = {
            "reward_terms": {"goal": r_goal, "action": r_action},
            "cost": cost,
            "safe": safe,
            "features": {"position": self._pos.astype(np.float32).copy()},
            "rescues": 0,
            "step": self._steps,
        }
        return self._obs(), reward, False, False, info

    def close(self) -> None:
        pass
