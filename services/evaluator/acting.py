"""The small acting interface the evaluator drives, and its two implementations.

``PolicyActing`` is what a collector runs (``ursa.policy.Policy``: the world model's filter and
the actor, weights from the learner); ``RandomActing`` is the collector's behaviour before any
weights arrive (uniform actions, φ = the provided feature itself). Both start each evaluation
from a fresh carry (``begin``) and act deterministically unless asked to explore.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ursa import scoring
from ursa.policy import Policy, PolicyCarry


class Acting(Protocol):
    """What the evaluator needs from a policy."""

    @property
    def version(self) -> int:
        """Version of the weights acting (0: none yet, the collector's initial behaviour)."""
        ...

    def begin(self) -> None:
        """Start a new evaluation (fresh recurrent state)."""

    def act(self, obs: np.ndarray, skill: np.ndarray) -> np.ndarray:
        """Action (A,) in [-1, 1] for ``obs`` (obs_dim,) while executing ``skill`` (D,)."""
        ...

    def features(self, inputs: np.ndarray) -> np.ndarray:
        """φ (M, D) of feature inputs (M, F) in skill space."""
        ...


class RandomActing:
    """Uniformly random actions (a collector's prefill); φ is the provided feature itself."""

    version = 0

    def __init__(self, act_dim: int, rng: np.random.Generator) -> None:
        self.act_dim = act_dim
        self.rng = rng

    def begin(self) -> None:
        pass

    def act(self, obs: np.ndarray, skill: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, size=self.act_dim)

    def features(self, inputs: np.ndarray) -> np.ndarray:
        return np.asarray(inputs, np.float64)


class PolicyActing:
    """A loaded ``ursa.policy.Policy`` from a fresh carry, acting by the scoring rule
    (``ursa.scoring.EXPLORE``: sampled actions) unless told otherwise."""

    def __init__(
        self, policy: Policy, rng: np.random.Generator, explore: bool = scoring.EXPLORE
    ) -> None:
        self.policy = policy
        self.rng = rng
        self.explore = explore
        self.carry: PolicyCarry = policy.initial_carry()

    @property
    def version(self) -> int:
        return max(int(self.policy.version), 0)

    def begin(self) -> None:
        self.carry = self.policy.initial_carry()
        # the RSSM latents are sampled too: draw them from this evaluation's generator, so
        # that an evaluation depends on its seed only, not on the evaluations before it
        self.policy.latent_rng = np.random.default_rng(self.rng.integers(0, 2**63 - 1))

    def act(self, obs: np.ndarray, skill: np.ndarray) -> np.ndarray:
        action, self.carry = self.policy.act(
            self.carry, obs, skill, explore=self.explore, rng=self.rng
        )
        return action

    def features(self, inputs: np.ndarray) -> np.ndarray:
        return self.policy.features(inputs)
