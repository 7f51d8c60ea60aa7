"""Coverage of a set of mean feature vectors over grids of cells (paper Figure 4).

A :class:`GridSpec` names some dimensions of a feature vector and splits their range into cells;
:func:`coverage_grid` counts how many points fall in each cell, and a cell is *covered* when at
least one point falls in it. On the A1 there is one 1-D grid per joint (the 12 mean joint angles
of ``vae_input``, each over the commandable range of its joint type); on the point env one 2-D
grid over the arena (the mean position).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ursa.config import Config

LEGS = ("FR", "FL", "RR", "RL")
JOINT_TYPES = ("hip", "upper", "lower")


@dataclass(frozen=True)
class GridSpec:
    """A grid of cells over some dimensions of a feature vector."""

    name: str
    """Label, e.g. ``FR hip`` or ``position``."""
    dims: tuple[int, ...]
    """Indices into the feature vector (G,)."""
    low: tuple[float, ...]
    """Lower end of each dimension's range (G,)."""
    high: tuple[float, ...]
    """Upper end of each dimension's range (G,)."""
    bins: tuple[int, ...]
    """Cells along each dimension (G,)."""

    @property
    def cells(self) -> int:
        return int(np.prod(self.bins))


def coverage_grid(
    points: np.ndarray, low: np.ndarray, high: np.ndarray, bins: int | tuple[int, ...]
) -> tuple[np.ndarray, int]:
    """Points per cell (bins_1, ..., bins_G) of ``points`` (K, G) on the grid splitting
    [low, high] (G,) into ``bins`` cells per dimension, and how many points lie outside.

    Cells are half-open [a, b) except the last one of each dimension, which includes ``high``.
    Points outside the box, or with a non-finite coordinate, are not counted in any cell.
    """
    pts = np.asarray(points, np.float64)
    lo = np.asarray(low, np.float64).reshape(-1)
    hi = np.asarray(high, np.float64).reshape(-1)
    g = len(lo)
    if pts.ndim != 2 or pts.shape[1] != g:
        raise ValueError(f"points must be (K, {g}), got {pts.shape}")
    nb = np.broadcast_to(np.asarray(bins, np.int64), (g,))
    if np.any(nb < 1) or np.any(hi <= lo):
        raise ValueError("need bins >= 1 and high > low")
    inside = np.isfinite(pts).all(1) & np.all((pts >= lo) & (pts <= hi), axis=1)
    frac = (pts[inside] - lo) / (hi - lo)
    idx = np.minimum((frac * nb).astype(np.int64), nb - 1)
    counts = np.zeros(tuple(int(b) for b in nb), np.int64)
    np.add.at(counts, tuple(idx.T), 1)
    return counts, int((~inside).sum())


def covered_cells(counts: np.ndarray) -> int:
    """Cells holding at least one point."""
    return int(np.count_nonzero(counts))


@dataclass
class Coverage:
    """Coverage of one set of points over several grids."""

    specs: list[GridSpec]
    counts: list[np.ndarray]
    """Points per cell, one array per spec."""
    outside: list[int]
    """Points outside each grid's box."""

    @property
    def covered(self) -> int:
        """Covered cells over all grids."""
        return sum(covered_cells(c) for c in self.counts)

    @property
    def total(self) -> int:
        """Cells over all grids."""
        return sum(s.cells for s in self.specs)

    def per_grid(self) -> dict[str, int]:
        return {s.name: covered_cells(c) for s, c in zip(self.specs, self.counts, strict=True)}


def coverage(points: np.ndarray, specs: list[GridSpec]) -> Coverage:
    """Coverage of ``points`` (K, F) over each grid of ``specs``."""
    pts = np.asarray(points, np.float64)
    counts, outside = [], []
    for s in specs:
        c, o = coverage_grid(pts[:, list(s.dims)], np.asarray(s.low), np.asarray(s.high), s.bins)
        counts.append(c)
        outside.append(o)
    return Coverage(specs, counts, outside)


def coverage_specs(cfg: Config, bins: int) -> tuple[str, list[GridSpec]]:
    """The ``info["features"]`` key whose means are binned, and the grids, for a run's env.

    A1: the 12 joint angles of ``vae_input``, one 1-D grid per joint over its joint type's
    commandable range (``A1Config.joint_low``..``joint_high``). Point env: the position, one
    2-D grid over the arena [-1, 1]².
    """
    if cfg.env == "a1":
        specs = []
        for leg_i, leg in enumerate(LEGS):
            for part_i, part in enumerate(JOINT_TYPES):
                specs.append(
                    GridSpec(
                        name=f"{leg} {part}",
                        dims=(3 * leg_i + part_i,),
                        low=(float(cfg.a1.joint_low[part_i]),),
                        high=(float(cfg.a1.joint_high[part_i]),),
                        bins=(bins,),
                    )
                )
        return "vae_input", specs
    if cfg.env == "point":
        return "position", [GridSpec("position", (0, 1), (-1.0, -1.0), (1.0, 1.0), (bins, bins))]
    raise ValueError(f"no coverage grid for env {cfg.env!r}")
