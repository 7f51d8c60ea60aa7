"""What values each producer declares it emits, and the pure checks consumers run at decode time.

A message that parses is not yet legitimate (DESIGN §4): every consumer rejects observations,
actions, features and skills outside the finite box their producer declares for the run's env
and feature function. The boxes follow from the env's physics and config, not from data:

- point env: positions in the arena [-1, 1]², velocities within ``max_speed``, actions and the
  previous action in [-1, 1];
- A1: actions in [-1, 1]; joint angles within ±2π rad, joint and base angular velocities within
  ±1000 rad/s, base linear velocity within ±100 m/s, gravity a unit vector, base height in
  [-1, 10] m, contacts 0/1 (generous: a legitimate state of a robot that is never reset must
  never be refused, whatever happens to it; a corrupted value of 10³⁰ always is);
- skills: a provided feature function's skill is a mean feature over T steps, so it lies in the
  feature box; a learned one (VAE latent mean, KL-regularised towards N(0, I)) within ±100;
- sampled skills (KDE draws, evaluation targets): the skill box widened by its own width on each
  side (the KDE's kernel reaches past the archive); the repertoire clips its draws to it.

``check`` raises ``OutOfBounds`` (a ``ValueError``); services count it and drop the message.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ursa.config import Config

LATENT_BOUND = 100.0
"""|z| bound of a learned skill (VAE latent mean)."""
WEIGHT_BOUND = 1e6
"""|w| bound of every policy or encoder weight."""
STAT_BOUND = 1e15
"""|x| bound of every Stats scalar and array entry (stats are counters, rates and states)."""


class OutOfBounds(ValueError):
    """Values outside the bounds their producer declares (or not finite)."""


@dataclass(frozen=True)
class Box:
    """A finite axis-aligned box [low, high] over the last axis of an array."""

    low: tuple[float, ...]
    high: tuple[float, ...]

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.low, float), np.asarray(self.high, float)
        if (
            lo.shape != hi.shape
            or lo.ndim != 1
            or not (np.isfinite(lo).all() and np.isfinite(hi).all())
        ):
            raise ValueError(f"a Box needs finite low/high of one length, got {self}")
        if (lo > hi).any():
            raise ValueError(f"Box low > high: {self}")

    @classmethod
    def uniform(cls, dim: int, low: float, high: float) -> Box:
        return cls((float(low),) * dim, (float(high),) * dim)

    @classmethod
    def concat(cls, *boxes: Box) -> Box:
        return cls(tuple(v for b in boxes for v in b.low), tuple(v for b in boxes for v in b.high))

    @property
    def dim(self) -> int:
        return len(self.low)

    def widened(self, factor: float = 1.0) -> Box:
        """The box grown by ``factor`` × its width on each side."""
        w = [(h - lo) * factor for lo, h in zip(self.low, self.high, strict=True)]
        return Box(
            tuple(lo - d for lo, d in zip(self.low, w, strict=True)),
            tuple(h + d for h, d in zip(self.high, w, strict=True)),
        )

    def contains(self, x: np.ndarray) -> np.ndarray:
        """Mask (...) of the rows of x (..., D) that are finite and inside the box."""
        a = np.asarray(x, dtype=np.float64)
        if a.shape[-1:] != (self.dim,):
            raise OutOfBounds(f"width {a.shape[-1:] or ()} where {self.dim} is declared")
        with np.errstate(invalid="ignore"):
            inside = (a >= np.asarray(self.low)) & (a <= np.asarray(self.high))
        return np.asarray(inside.all(axis=-1))

    def clip(self, x: np.ndarray) -> np.ndarray:
        return np.clip(x, np.asarray(self.low), np.asarray(self.high))


def check(name: str, x: np.ndarray, box: Box) -> np.ndarray:
    """Return x (..., D) as float64 if every row is finite and inside ``box``; else raise
    ``OutOfBounds`` naming the first offending value."""
    a = np.asarray(x, dtype=np.float64)
    ok = box.contains(a)
    if not ok.all():
        bad = np.argwhere(~ok)[0]
        row = a[tuple(bad)]
        lo, hi = np.asarray(box.low), np.asarray(box.high)
        with np.errstate(invalid="ignore"):
            col = int(np.argmax(~((row >= lo) & (row <= hi))))
        raise OutOfBounds(
            f"{name}{list(bad.tolist())}[{col}] = {float(row[col])!r} outside "
            f"[{lo[col]:g}, {hi[col]:g}]"
        )
    return a


def check_finite(name: str, x: np.ndarray, bound: float) -> np.ndarray:
    """Return x if every value is finite with |x| ≤ bound; else raise ``OutOfBounds``."""
    a = np.asarray(x)
    if a.dtype.kind in "fc" or a.dtype.kind in "iub":
        af = a.astype(np.float64, copy=False)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(af) & (np.abs(af) <= bound)
        if not ok.all():
            i = tuple(np.argwhere(~ok)[0].tolist())
            raise OutOfBounds(f"{name}{list(i)} = {float(af[i])!r} is not finite within ±{bound:g}")
    return a


@dataclass(frozen=True)
class Declared:
    """Every box a run's producers declare (see the module docstring)."""

    obs: Box
    action: Box
    features: Box
    """The feature input collectors send: the VAE input (learned φ) or the provided φ."""
    skills: Box
    """Skills of the archive."""
    samples: Box
    """Skills drawn from the KDE or asked for (targets)."""
    feature_dims: dict[str, Box]
    """Box of every feature function the env provides, by name."""


def _a1_boxes() -> tuple[Box, dict[str, Box]]:
    two_pi = 2.0 * np.pi
    joints = Box.uniform(12, -two_pi, two_pi)
    height = Box((-1.0,), (10.0,))
    obs = Box.concat(
        joints,
        Box.uniform(12, -1000.0, 1000.0),
        Box.uniform(3, -1.0001, 1.0001),
        Box.uniform(3, -1000.0, 1000.0),
        Box.uniform(3, -100.0, 100.0),
        height,
        Box.uniform(12, -1.0, 1.0),
    )
    feats = {
        "vae_input": Box.concat(joints, height),
        "velocity": Box((-100.0, -1000.0), (100.0, 1000.0)),
        "contacts": Box.uniform(4, 0.0, 1.0),
    }
    return obs, feats


def _point_boxes(max_speed: float) -> tuple[Box, dict[str, Box]]:
    v = abs(float(max_speed))
    obs = Box.concat(Box.uniform(2, -1.0, 1.0), Box.uniform(2, -v, v), Box.uniform(2, -1.0, 1.0))
    return obs, {"position": Box.uniform(2, -1.0, 1.0)}


def declared(cfg: Config) -> Declared:
    """The boxes of a run's config (env, feature function, skill dimension)."""
    if cfg.env == "a1":
        obs, feats = _a1_boxes()
        action = Box.uniform(12, -1.0, 1.0)
    else:
        obs, feats = _point_boxes(cfg.point.max_speed)
        action = Box.uniform(2, -1.0, 1.0)
    if cfg.feature == "vae":
        features = feats["vae_input"]
        skills = Box.uniform(cfg.repertoire.dim, -LATENT_BOUND, LATENT_BOUND)
    else:
        features = skills = feats[cfg.feature]
    return Declared(
        obs=obs,
        action=action,
        features=features,
        skills=skills,
        samples=skills.widened(1.0),
        feature_dims=feats,
    )


__all__ = [
    "LATENT_BOUND",
    "STAT_BOUND",
    "WEIGHT_BOUND",
    "Box",
    "Declared",
    "OutOfBounds",
    "check",
    "check_finite",
    "declared",
]
