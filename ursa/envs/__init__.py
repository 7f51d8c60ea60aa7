"""Reset-free environments: the Unitree A1 of the paper and a tiny point-mass stand-in.

``make_env(name, seed, **overrides)`` builds one by name; overrides are fields of the env's
config dataclass (``A1Config`` or ``PointConfig``).
"""

from __future__ import annotations

from typing import Any

from ursa.envs.a1 import (
    ACT_DIM,
    DAMAGE_SCENARIOS,
    FEATURE_DIMS,
    JOINT_NAMES,
    OBS_DIM,
    OBS_LAYOUT,
    A1Config,
    A1Env,
)
from ursa.envs.base import ResetFreeEnv
from ursa.envs.point import PointConfig, PointEnv

ENV_NAMES = ("a1", "point")
NO_DAMAGE = ("", "none")
"""Damage names that mean the intact robot."""

__all__ = [
    "ACT_DIM",
    "DAMAGE_SCENARIOS",
    "ENV_NAMES",
    "FEATURE_DIMS",
    "JOINT_NAMES",
    "NO_DAMAGE",
    "OBS_DIM",
    "OBS_LAYOUT",
    "A1Config",
    "A1Env",
    "PointConfig",
    "PointEnv",
    "ResetFreeEnv",
    "allowed_damages",
    "make_env",
]


def make_env(name: str, seed: int = 0, **overrides: Any) -> ResetFreeEnv:
    """Build the reset-free env ``name`` (``"a1"`` or ``"point"``) with config ``overrides``.

    ``make_env("a1")`` is the forward task; ``make_env("a1", task="posture")`` the posture task;
    e.g. ``make_env("a1", damage="front_upper", rescue=False)`` for a damaged robot.
    """
    if name == "a1":
        return A1Env(A1Config(**overrides), seed=seed)
    if name == "point":
        return PointEnv(PointConfig(**overrides), seed=seed)
    raise ValueError(f"unknown env {name!r}; expected one of {ENV_NAMES}")


def allowed_damages(env: str) -> tuple[str, ...]:
    """Damage names an evaluation may ask for on ``env`` (:data:`NO_DAMAGE`: intact; on the A1
    each of :data:`DAMAGE_SCENARIOS`)."""
    if env == "a1":
        return (*NO_DAMAGE, *sorted(DAMAGE_SCENARIOS))
    return NO_DAMAGE
