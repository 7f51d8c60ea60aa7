"""A point env that reports rescues, for the tests of everything that must handle one."""

from __future__ import annotations

import numpy as np

from ursa.envs.point import PointEnv


class RescuedPoint(PointEnv):
    """The point env with a rescue reported at the given step indices (as the A1 reports a
    rescue teleport in ``info["rescued"]``); ``n`` counts the steps taken."""

    def __init__(self, at: set[int], seed: int = 0) -> None:
        super().__init__(seed=seed)
        self.at, self.n = at, 0

    def step(self, action: np.ndarray):  # type: ignore[no-untyped-def]
        out = super().step(action)
        out[4]["rescued"] = self.n in self.at
        self.n += 1
        return out
