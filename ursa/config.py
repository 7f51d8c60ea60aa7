"""The whole core config, assembled from each component's config, and its presets.

Presets (``tiny`` for tests, ``point`` the point-env learning recipe, ``small`` the CPU sizes
the benchmarks measure, ``cpu`` the A1's CPU recipe, ``paper`` for the paper's sizes) change
sizes and rates, never code paths. Every service reads the same ``Config`` and saves what it
resolved.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

from ursa.envs.a1 import A1Config
from ursa.envs.base import ResetFreeEnv
from ursa.envs.point import PointConfig
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.pace import PaceMode
from ursa.repertoire import RepertoireConfig

PresetName = Literal["tiny", "point", "small", "cpu", "paper"]
EnvName = Literal["a1", "point"]

#: Dimension of each provided feature function, by env (the learned one is ``vae``).
PROVIDED_FEATURES: dict[str, dict[str, int]] = {
    "a1": {"velocity": 2, "contacts": 4},
    "point": {"position": 2},
}
VAE_INPUT_DIM = {"a1": 13}
"""Size of the learned feature function's input (joint angles + base height on the A1)."""


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
    pace: PaceMode = "wait"
    """Rate limiter (``ursa.pace``): ``wait`` (simulation) pauses collectors while the learner's
    replay ratio is more than ``pace_tolerance`` below its ``train_ratio``; ``free`` (a real
    robot) never waits, and the learner reports the ratio it reaches."""
    pace_tolerance: float = 0.1
    """Relative shortfall of the replay ratio below its target before collectors wait."""
    random_scale: float = 1.0
    """Uniformly random actions (the prefill, and until the first weights arrive) lie in
    [−s, s]^A. 1 is the whole action box; the A1's posture task needs less, since every
    action of the whole box breaks its posture limits (docs/learner.md)."""
    archive_window: int = 1
    """The repertoire admits the mean feature input of each block of this many consecutive
    safe steps (``Chunk.archive_features``); 1: every safe step's own. Must divide
    ``chunk_len`` so that no step is dropped."""

    def __post_init__(self) -> None:
        if self.archive_window < 1 or self.chunk_len % self.archive_window:
            raise ValueError(
                f"archive_window ({self.archive_window}) must be >= 1 and divide "
                f"chunk_len ({self.chunk_len})"
            )


@dataclass(frozen=True)
class Config:
    """Everything the algorithm needs; shared by every service."""

    preset: PresetName = "small"
    """Which preset produced the sizes below (recorded in the run directory)."""
    env: EnvName = "a1"
    """``a1``: the reset-free Unitree A1 in PyBullet; ``point``: the tiny point-mass arena."""
    feature: str = "vae"
    """Feature function phi: ``vae`` (learned, URSA) or the name of a provided feature of the env
    (``velocity`` or ``contacts`` on the A1; ``position`` on the point env)."""
    a1: A1Config = field(default_factory=A1Config)
    """The A1 environment (task, damage, rescue, gains...)."""
    point: PointConfig = field(default_factory=PointConfig)
    """The point environment."""
    collector: CollectorConfig = field(default_factory=lambda: _collector("small"))
    """How collectors act and report (T, chunk length, rate limiter)."""
    repertoire: RepertoireConfig = field(default_factory=lambda: _repertoire("small", "a1", "vae"))
    """The archive of skills (N_R, D, N_z, the KDE's support)."""
    learner: LearnerConfig = field(default_factory=LearnerConfig.small)
    """World model, critics, multipliers, actor and VAE (``mode`` picks URSA or a baseline).
    ``Config()`` is ``preset("small")``: the A1 with the learned feature function."""

    @property
    def learned_feature(self) -> bool:
        return self.feature == "vae"

    @property
    def feature_input_key(self) -> str:
        """Key of ``info["features"]`` that collectors send as the feature input."""
        return "vae_input" if self.learned_feature else self.feature

    @property
    def skill_dim(self) -> int:
        return self.repertoire.dim


# The one preset table: every named recipe's sizes (the learner's are in ``learner_preset``).
_REPERTOIRE_SIZE = {"tiny": 300, "point": 1000, "small": 2000, "cpu": 2000, "paper": 5000}
_SKILL_PERIOD = {"tiny": 100, "point": 250, "small": 250, "cpu": 250, "paper": 250}
_CHUNK_LEN = {"tiny": 25, "point": 25, "small": 50, "cpu": 50, "paper": 50}
PREFILL = {"tiny": 2000, "point": 2000, "small": 2000, "cpu": 2000, "paper": 2000}
"""Env steps of uniformly random actions before the first update (the serial loop; the
learner service's ``--min-replay``)."""
TRAIN_STEPS = {"point": 12_000, "cpu": 20_000}
"""Env steps of a recipe shown to learn (the prefill included): the point recipe's 12,000 give
3000 updates at train_ratio 128 with batches of 16 × 32; the A1 CPU recipe's 20,000 give 1250
updates at train_ratio 32. Safe from (updates): 750 / 1062 / 688 (seeds 0–2, EPYC, bf16),
688 / 750 (seeds 0 / 1, Xeon with AMX, bf16 and float32 alike for seed 0); at 1000 updates a
seed-0 run on a Xeon without bf16 was not yet safe (violation 0.579 over its last 2000 steps, CI
of 2026-12-04), so the budget keeps ~190 updates past the latest seen (docs/NOTES.md)."""


def _feature_dims(env: str, feature: str) -> tuple[int, int | None]:
    """(D, F) of a feature function on ``env``: the skill dimension and the size of the VAE's
    input (None for a provided feature)."""
    if feature == "vae":
        if env not in VAE_INPUT_DIM:
            raise ValueError(f"the learned feature function needs the A1, not {env!r}")
        return 3, VAE_INPUT_DIM[env]
    dims = PROVIDED_FEATURES[env]
    if feature not in dims:
        raise ValueError(f"env {env!r} provides {sorted(dims)}, not {feature!r}")
    return dims[feature], None


def with_feature(cfg: Config, feature: str) -> Config:
    """Set the feature function and the repertoire dimensions that follow from it."""
    dim, input_dim = _feature_dims(cfg.env, feature)
    rep = dataclasses.replace(cfg.repertoire, dim=dim, input_dim=input_dim)
    mode = cfg.learner.mode
    if mode != "daydreamer":
        mode = "ursa" if feature == "vae" else "ursa-supervised"
    learner = dataclasses.replace(cfg.learner, mode=mode, skill_dim=rep.dim)
    return dataclasses.replace(cfg, feature=feature, repertoire=rep, learner=learner)


def _collector(name: PresetName) -> CollectorConfig:
    return CollectorConfig(skill_period=_SKILL_PERIOD[name], chunk_len=_CHUNK_LEN[name])


def _repertoire(name: PresetName, env: str, feature: str) -> RepertoireConfig:
    dim, input_dim = _feature_dims(env, feature)
    return RepertoireConfig(size=_REPERTOIRE_SIZE[name], dim=dim, input_dim=input_dim)


def preset(name: PresetName, env: EnvName | None = None, feature: str | None = None) -> Config:
    """The config of a preset, on ``env`` (default a1) with ``feature`` (default: vae on the
    A1, position on the point env)."""
    env_name: EnvName = env or "a1"
    cfg = Config(
        preset=name,
        env=env_name,
        collector=_collector(name),
        repertoire=RepertoireConfig(size=_REPERTOIRE_SIZE[name]),
        learner=learner_preset(name),
    )
    return with_feature(cfg, feature or ("vae" if env_name == "a1" else "position"))


def build_env(cfg: Config, seed: int = 0, damage: str | None = None) -> ResetFreeEnv:
    """The environment a collector (or the evaluator) runs; ``damage`` overrides the config's
    damage scenario (empty string: intact)."""
    if cfg.env == "a1":
        from ursa.envs.a1 import A1Env

        a1 = cfg.a1 if damage is None else dataclasses.replace(cfg.a1, damage=damage or None)
        return A1Env(a1, seed=seed)
    from ursa.envs.point import PointEnv

    return PointEnv(cfg.point, seed=seed)
