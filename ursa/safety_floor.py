"""An integrating floor under the safety multiplier λ2, driven by the acting policy's real
violation rate (``LearnerConfig.lambda2_floor_*``; docs/learner.md).

QDAC's λ2(s, z) is trained by cross-entropy to predict whether the imagined cost return from
(s, z) is positive: it estimates a probability, which a safe policy drives down, and then the
skill term takes the actor back out of the safe set (measured on the A1's posture task). A
classic Lagrange multiplier integrates the constraint's violation instead: it rises while the
real violation rate is above its target and falls only while it is below. The actor weighs the
cost with max(λ2(s, z), floor). The two functions here are the whole rule; the collector side
(the serial loop, the learner service) keeps the rate, the learner the floor.
"""

from __future__ import annotations

import numpy as np


def ema_rate(rate: float | None, unsafe: np.ndarray, window: int) -> float:
    """Exponential average, time constant ``window`` steps, of the flags ``unsafe`` (n,) (1 for
    an unsafe step) appended in order to the average ``rate`` (None: no step seen yet, the
    average starts at the flags' mean). Equal to n single-step updates r ← r + (u − r)/window."""
    u = np.asarray(unsafe, np.float64).ravel()
    n = len(u)
    if n == 0:
        if rate is None:
            raise ValueError("no steps and no previous rate")
        return float(rate)
    if rate is None:
        rate = float(u.mean())
    keep = 1.0 - 1.0 / window
    weights = (1.0 / window) * keep ** np.arange(n - 1, -1, -1, dtype=np.float64)
    return float(rate * keep**n + weights @ u)


def floor_step(floor: float, rate: float, target: float, lr: float, high: float) -> float:
    """One step of the floor: clip(floor + lr·(rate − target), 0, high)."""
    return float(min(max(floor + lr * (rate - target), 0.0), high))
