"""Bounded time series for live plots that stay small over runs of any length.

A :class:`DecimatingSeries` keeps at most ``capacity`` points. When it fills up, neighbouring
pairs are averaged (halving the count) and the minimum spacing between recorded points doubles,
so an hour-long run and a day-long run both fit in the same memory, at a resolution that
coarsens with the age of the run rather than dropping its beginning. :func:`align` resamples
several series onto one shared x grid of at most ``max_points`` (uPlot's aligned data).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class DecimatingSeries:
    """At most ``capacity`` (t, v) points; see the module docstring. Not thread-safe."""

    def __init__(self, capacity: int = 2048, min_dt: float = 0.25) -> None:
        if capacity < 4:
            raise ValueError("capacity must be at least 4")
        self.capacity = capacity - capacity % 2
        self.min_dt = float(min_dt)
        self._t = np.empty(self.capacity)
        self._v = np.empty(self.capacity)
        self._n = 0
        self._start = -math.inf
        self._count = 0
        self.compactions = 0

    def __len__(self) -> int:
        return self._n

    def add(self, t: float, v: float) -> None:
        """Record v at time t. Samples closer than ``min_dt`` to the start of the last point's
        bucket are averaged into it (time and value); non-finite or out-of-order ones are
        ignored."""
        if not (math.isfinite(t) and math.isfinite(v)):
            return
        n = self._n
        if n and t < self._start:
            return
        if n and t - self._start < self.min_dt:
            self._count += 1
            self._t[n - 1] += (t - self._t[n - 1]) / self._count
            self._v[n - 1] += (v - self._v[n - 1]) / self._count
            return
        if n == self.capacity:
            self._compact()
            n = self._n
        self._t[n] = t
        self._v[n] = v
        self._n = n + 1
        self._start = t
        self._count = 1

    def _compact(self) -> None:
        n = self._n
        self._t[: n // 2] = self._t[:n].reshape(-1, 2).mean(axis=1)
        self._v[: n // 2] = self._v[:n].reshape(-1, 2).mean(axis=1)
        self._n = n // 2
        span = float(self._t[self._n - 1] - self._t[0]) if self._n > 1 else 0.0
        self.min_dt = max(2.0 * self.min_dt, span / self.capacity)
        self.compactions += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies (t (n,), v (n,))."""
        return self._t[: self._n].copy(), self._v[: self._n].copy()

    @property
    def last(self) -> float | None:
        return float(self._v[self._n - 1]) if self._n else None


def align(
    series: Sequence[tuple[np.ndarray, np.ndarray]], max_points: int = 400
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Resample series [(t (n_i,), v (n_i,))] onto one grid x (M,), M ≤ ``max_points``.

    Each series is averaged into M equal-width bins of the common time span; an empty bin takes
    the linear interpolation of the series at the bin centre (constant before its first and
    after its last point), so uPlot never sees a gap or a NaN. Returns (x, [y_i (M,)]).
    """
    series = [(t, v) for t, v in series if len(t)]
    if not series:
        return np.zeros(0), []
    t0 = min(float(t[0]) for t, _ in series)
    t1 = max(float(t[-1]) for t, _ in series)
    longest = max(len(t) for t, _ in series)
    m = max(1, min(max_points, longest))
    if t1 <= t0 or m == 1:
        return np.array([t1]), [np.array([float(v[-1])]) for _, v in series]
    edges = np.linspace(t0, t1, m + 1)
    x = 0.5 * (edges[:-1] + edges[1:])
    ys = []
    for t, v in series:
        idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, m - 1)
        sums = np.bincount(idx, weights=v, minlength=m)
        counts = np.bincount(idx, minlength=m)
        y = np.interp(x, t, v)
        has = counts > 0
        y[has] = sums[has] / counts[has]
        ys.append(y)
    return x, ys
