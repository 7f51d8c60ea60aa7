"""The whole core config, assembled from each component's config, and its presets.

Presets (``tiny`` for tests, ``small`` for a CPU, ``paper`` for the paper's sizes) change sizes,
never code paths. Every service reads the same ``Config`` and saves what it resolved.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

PresetName = Literal["tiny", "small", "paper"]


@dataclass(frozen=True)
class EnvSpec:
    """Which environment the collectors run."""

    name: Literal["a1", "point"] = "a1"
    """``a1``: the reset-free Unitree A1 in PyBullet; ``point``: the tiny point-mass arena."""
    task: Literal["forward", "posture"] = "forward"
    """A1 task (paper §5.2 forward, §5.3 posture); ignored by the point env."""
    damage: str = ""
    """Damage scenario of the A1 (e.g. ``front_upper``); empty for an intact robot."""
    rescue: bool = True
    """Right the A1 after a run of unsafe steps (a counted human intervention)."""


@dataclass(frozen=True)
class CollectorConfig:
    """How collectors act and report."""

    skill_period: int = 250
    """T: steps between two skills drawn from the repertoire's KDE."""
    chunk_len: int = 50
    """Transitions per published chunk."""
    stats_hz: float = 10.0
    """How often a collector publishes its stats (joint angles for the live view included)."""
    violation_window: int = 1000
    """Steps in the sliding window of the safety-violation rate."""
    prefill_random: bool = True
    """Act uniformly at random until the first weights arrive (else the initial actor acts)."""


@dataclass(frozen=True)
class Config:
    """Everything the algorithm needs; shared by every service."""

    preset: PresetName = "small"
    """Which preset produced the sizes below (recorded for the run directory)."""
    env: EnvSpec = field(default_factory=EnvSpec)
    feature: str = "vae"
    """Feature function phi: ``vae`` (learned, URSA) or the name of a provided feature of the env
    (``velocity``, ``contacts`` on the A1; ``position`` on the point env)."""
    collector: CollectorConfig = field(default_factory=CollectorConfig)


def preset(name: PresetName, env: Literal["a1", "point"] | None = None) -> Config:
    """The config of a preset (optionally on another env)."""
    cfg = Config(preset=name)
    if name == "tiny":
        cfg = dataclasses.replace(
            cfg, collector=dataclasses.replace(cfg.collector, skill_period=100, chunk_len=25)
        )
    if env is not None:
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, name=env))
    if cfg.env.name == "point" and cfg.feature == "vae":
        cfg = dataclasses.replace(cfg, feature="position")
    return cfg
