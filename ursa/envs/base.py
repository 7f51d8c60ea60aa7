"""The interface every reset-free environment of URSA implements.

A reset-free environment is constructed once, ``reset`` is called once to get the first
observation, and from then on it is only ever stepped. ``step`` follows gymnasium's signature
(``obs, reward, terminated, truncated, info``); ``terminated`` and ``truncated`` are always
False, because there are no episodes. A later ``reset`` call does not touch the simulation: it
returns the current observation and counts the call in ``info["reset_calls"]``.

Every step's ``info`` holds:

- ``"reward_terms"``: dict of every reward term by name (float each)
- ``"cost"``: float, the cost c(s, a); the state is safe iff ``cost <= 0``
- ``"safe"``: bool
- ``"features"``: dict ``name -> np.ndarray (F,)`` of every feature function the env provides;
  ``"vae_input"`` is the input of the learned feature function where the env has one
- ``"rescues"``: int, the number of rescues so far (0 where the env has none)
- ``"step"``: int, control steps since construction
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class ResetFreeEnv(Protocol):
    """What collectors, the learner's tests and the evaluator rely on."""

    obs_dim: int
    act_dim: int
    feature_dims: dict[str, int]
    """Dimension of each feature function in ``info["features"]``."""

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]: ...

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]: ...

    def close(self) -> None: ...
