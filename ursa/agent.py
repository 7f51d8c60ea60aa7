"""Actor, critics, Lagrange multipliers and the math of URSA's imagination training (§3.1, §4.1).

- ``Actor``: π(a | s, z), a tanh-squashed Gaussian over [−1, 1]^A.
- ``TwoHotCritic``: V(s, z) on the reward and C(s, z) on the cost (two-hot over symexp bins).
- ``SFCritic``: the successor features in discounted-average units, m(s, z) = (1 − γ) ψ(s, z),
  parameterised as z + MLP(s, z) (see docs/learner.md).
- ``Multiplier``: λ_i(s, z) = sigmoid(MLP(s, z)).
- ``Critics``: V, ψ and C with their slow copies, one bundle over one joint input [s, z].
- Pure functions: :func:`lambda_return`, :func:`mahalanobis`, :func:`whitened_sq`,
  :func:`actor_objective`,
  :func:`percentile_update`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TypeVar

import torch
from torch import nn

from ursa.distributions import tanh_normal_logp, tanh_normal_rsample
from ursa.learner_config import LearnerConfig
from ursa.networks import MLP, cast_input

_M = TypeVar("_M", bound=nn.Module)


def lambda_return(
    reward: torch.Tensor, value: torch.Tensor, discount: float, lam: float
) -> torch.Tensor:
    """TD(λ) returns (H, ...) of an imagined rollout.

    reward (H, ...): reward[t] is received on the step s_t -> s_{t+1}; value (H+1, ...):
    value[t] estimates the return from s_t. ``R_H = value[H]`` and
    ``R_t = reward[t] + γ · ((1 − λ) · value[t+1] + λ · R_{t+1})``.
    """
    horizon = reward.shape[0]
    out = []
    ret = value[horizon]
    for t in reversed(range(horizon)):
        ret = reward[t] + discount * ((1.0 - lam) * value[t + 1] + lam * ret)
        out.append(ret)
    return torch.stack(out[::-1])


def mahalanobis(x: torch.Tensor, whiten: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """‖x‖_Σ (...) of differences x (..., D), with ``whiten`` A (D, D) such that A Σ Aᵀ = I.

    ``eps`` inside the square root keeps the gradient finite at 0.
    """
    y = x @ whiten.T
    return torch.sqrt(y.pow(2).sum(-1) + eps)


def whitened_sq(x: torch.Tensor, whiten: torch.Tensor) -> torch.Tensor:
    """Squared Mahalanobis norm ‖x‖²_Σ (...) of x (..., D), A (D, D) with A Σ Aᵀ = I (smooth
    at 0, unlike the square of :func:`mahalanobis`)."""
    return (x @ whiten.T).pow(2).sum(-1)


def actor_objective(
    value: torch.Tensor,
    distance: torch.Tensor,
    delta: float | torch.Tensor,
    cost: torch.Tensor,
    lam1: torch.Tensor,
    lam2: torch.Tensor,
) -> torch.Tensor:
    """J_π = (1−λ1)(1−λ2)·V − λ1(1−λ2)·(‖(1−γ)ψ − z‖ − δ) − λ2·C (paper §4.1), elementwise.

    value, distance, cost, lam1, lam2: same shape (...); each term arrives already normalised.
    """
    return (
        (1.0 - lam1) * (1.0 - lam2) * value - lam1 * (1.0 - lam2) * (distance - delta) - lam2 * cost
    )


def cap_safe_margin(cost: torch.Tensor, cap: float) -> torch.Tensor:
    """max(c, −cap), elementwise (any shape): margins deeper inside the safe set than ``cap``
    earn nothing more. Costs above −cap (violations included) pass unchanged, gradient too."""
    return cost.clamp(min=-cap)


def any_ahead(flag: torch.Tensor) -> torch.Tensor:
    """Whether ``flag`` (H, N) holds at step t or at any later step: out[t] = max_{k ≥ t} flag[k]
    (H, N), as float."""
    f = flag.float()
    return torch.flip(torch.cummax(torch.flip(f, (0,)), dim=0).values, (0,))


def percentile_update(
    low: torch.Tensor, high: torch.Tensor, x: torch.Tensor, rate: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """EMA update of the 5th and 95th percentiles of x (any shape): returns (low', high')."""
    flat = x.detach().flatten().float()
    q = torch.quantile(flat, torch.tensor([0.05, 0.95], device=flat.device))
    return (1.0 - rate) * low + rate * q[0], (1.0 - rate) * high + rate * q[1]


class ReturnNorm(nn.Module):
    """DreamerV3 return normalisation: scale = max(limit, EMA(P95) − EMA(P5))."""

    low: torch.Tensor
    high: torch.Tensor

    def __init__(self, rate: float, limit: float) -> None:
        super().__init__()
        self.rate, self.limit = rate, limit
        self.register_buffer("low", torch.zeros(()))
        self.register_buffer("high", torch.zeros(()))

    def update(self, x: torch.Tensor) -> None:
        """Fold the batch of returns x (any shape) into the percentile EMAs."""
        low, high = percentile_update(self.low, self.high, x, self.rate)
        self.low.copy_(low)
        self.high.copy_(high)

    def scale(self) -> torch.Tensor:
        """The divisor () of the returns."""
        return torch.clamp(self.high - self.low, min=self.limit)


class Actor(nn.Module):
    """π(a | s, z): tanh of a Gaussian with std in [min_std, max_std]; mean 0 and a wide std at
    initialisation, so the untrained actor acts at random (and tanh(mean) = 0 in eval mode)."""

    def __init__(self, config: LearnerConfig, feat_dim: int, skill_dim: int, act_dim: int) -> None:
        super().__init__()
        self.min_std, self.max_std = config.actor_min_std, config.actor_max_std
        self.act_dim = act_dim
        self.mlp = MLP(
            feat_dim + skill_dim, 2 * act_dim, config.units, config.layers, zero_out=True
        )

    def forward(self, feat: torch.Tensor, skill: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(..., F), (..., D) -> pre-tanh mean and std (..., A)."""
        mean, raw = self.mlp(torch.cat([feat, skill], -1)).chunk(2, -1)
        std = (self.max_std - self.min_std) * torch.sigmoid(raw + 2.0) + self.min_std
        return mean, std

    def sample(
        self, feat: torch.Tensor, skill: torch.Tensor, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reparameterised action (..., A), its log-density (...) and the pre-tanh sample
        (..., A)."""
        mean, std = self(feat, skill)
        return tanh_normal_rsample(mean, std, generator)

    def log_prob(self, feat: torch.Tensor, skill: torch.Tensor, pre: torch.Tensor) -> torch.Tensor:
        """log π(tanh(pre) | s, z) (...) for fixed pre-tanh samples (..., A) (score function)."""
        mean, std = self(feat, skill)
        return tanh_normal_logp(mean, std, pre)

    def mode(self, feat: torch.Tensor, skill: torch.Tensor) -> torch.Tensor:
        """Deterministic action tanh(mean) (..., A)."""
        return torch.tanh(self(feat, skill)[0])


def joint_input(feat: torch.Tensor, skill: torch.Tensor) -> torch.Tensor:
    """[s, z] (..., F + D) of model states (..., F) and skills (..., D), the input of every
    critic and multiplier, in the networks' compute dtype (cast once for all of them)."""
    return cast_input(torch.cat([feat, skill], -1))


class TwoHotCritic(nn.Module):
    """A scalar critic over (s, z) with a two-hot output (V on the reward, C on the cost)."""

    bins: torch.Tensor

    def __init__(
        self, config: LearnerConfig, feat_dim: int, skill_dim: int, bins: torch.Tensor
    ) -> None:
        super().__init__()
        self.mlp = MLP(
            feat_dim + skill_dim, config.bins, config.units, config.layers, zero_out=True
        )
        self.register_buffer("bins", bins.clone(), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Joint input (..., F + D) (:func:`joint_input`) -> logits (..., K); the value is
        ``two_hot_mean(logits, bins)``."""
        return self.mlp(x)


class SFCritic(nn.Module):
    """m(s, z) = (1 − γ) ψ(s, z) (..., D), regressed per dimension (squared error).

    Predicting the discounted *average* keeps the output on the features' own scale whatever γ;
    the residual form m = z + MLP(s, z) makes "the skill is achieved" the initial guess, so the
    network only has to learn the offset, which is small wherever the skill is executed.
    """

    def __init__(self, config: LearnerConfig, feat_dim: int, skill_dim: int) -> None:
        super().__init__()
        self.mlp = MLP(feat_dim + skill_dim, skill_dim, config.units, config.layers, zero_out=True)
        self.residual = config.sf_residual

    def forward(self, x: torch.Tensor, skill: torch.Tensor) -> torch.Tensor:
        """Joint input (..., F + D), skill (..., D) in float32 (the residual's base) ->
        (..., D)."""
        out = self.mlp(x)
        return skill + out if self.residual else out


class Multiplier(nn.Module):
    """λ(s, z) = sigmoid(MLP(s, z)), one hidden layer; 0.5 at initialisation."""

    def __init__(self, config: LearnerConfig, feat_dim: int, skill_dim: int) -> None:
        super().__init__()
        self.mlp = MLP(feat_dim + skill_dim, 1, config.lagrange_units, 1, zero_out=True)

    def logit(self, x: torch.Tensor) -> torch.Tensor:
        """Joint input (..., F + D) -> logit (...)."""
        return self.mlp(x).squeeze(-1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """λ in (0, 1) (...)."""
        return torch.sigmoid(self.logit(x))


@dataclass(frozen=True)
class CriticOutputs:
    """What the critics predict at joint inputs (...): V's logits (..., K), m = (1 − γ)ψ
    (..., D) and C's logits (..., K); ``sf`` and ``cost_logits`` are None in ``daydreamer``
    mode."""

    value_logits: torch.Tensor
    sf: torch.Tensor | None
    cost_logits: torch.Tensor | None


class Critics(nn.Module):
    """The critics of imagination training as one bundle: V on the reward and, when the policy
    is skill-conditioned, ψ (as m = (1 − γ)ψ) and C on the cost, each with a slow copy that
    follows it by EMA and regularises its output (DreamerV3's ``critic_slowreg``).

    Every member reads the same joint input [s, z] (:func:`joint_input`). Members are created
    in the order V, ψ, C, so a seed gives the same initial weights as separate critics did.
    Batching the three MLPs into one (stacked weights, ``bmm``) was measured slower on a CPU
    than three matrix products (docs/learner.md).
    """

    def __init__(
        self,
        config: LearnerConfig,
        feat_dim: int,
        skill_dim: int,
        bins: torch.Tensor,
        skills: bool,
    ) -> None:
        super().__init__()
        self.value = TwoHotCritic(config, feat_dim, skill_dim, bins)
        self.sf = SFCritic(config, feat_dim, skill_dim) if skills else None
        self.cost = TwoHotCritic(config, feat_dim, skill_dim, bins) if skills else None
        self.value_slow = frozen_copy(self.value)
        self.sf_slow = frozen_copy(self.sf) if self.sf is not None else None
        self.cost_slow = frozen_copy(self.cost) if self.cost is not None else None

    def _members(self, slow: bool) -> tuple[TwoHotCritic, SFCritic | None, TwoHotCritic | None]:
        if slow:
            return self.value_slow, self.sf_slow, self.cost_slow
        return self.value, self.sf, self.cost

    def _predict(self, slow: bool, x: torch.Tensor, skill: torch.Tensor) -> CriticOutputs:
        value, sf, cost = self._members(slow)
        return CriticOutputs(
            value(x),
            sf(x, skill) if sf is not None else None,
            cost(x) if cost is not None else None,
        )

    def online(self, x: torch.Tensor, skill: torch.Tensor) -> CriticOutputs:
        """The online critics at joint inputs x (..., F + D) for skills (..., D)."""
        return self._predict(False, x, skill)

    @torch.no_grad()
    def slow(self, x: torch.Tensor, skill: torch.Tensor) -> CriticOutputs:
        """The slow copies at joint inputs x (..., F + D) for skills (..., D)."""
        return self._predict(True, x, skill)

    def online_parameters(self) -> list[nn.Parameter]:
        """The parameters the critics' optimiser trains (the slow copies follow by EMA)."""
        return [p for m in self._members(False) if m is not None for p in m.parameters()]

    @torch.no_grad()
    def update_slow(self, rate: float) -> None:
        """Move every slow copy ``rate`` of the way to its online critic."""
        for slow, fast in zip(self._members(True), self._members(False), strict=True):
            if slow is not None and fast is not None:
                for ps, pf in zip(slow.parameters(), fast.parameters(), strict=True):
                    ps.lerp_(pf, rate)

    def members(self) -> dict[str, nn.Module]:
        """Every member by its checkpoint name (``value``, ``value_slow``, ``sf``...)."""
        names = ("value", "sf", "cost")
        out: dict[str, nn.Module] = {}
        for name, fast, slow in zip(names, self._members(False), self._members(True), strict=True):
            if fast is not None and slow is not None:
                out[name], out[f"{name}_slow"] = fast, slow
        return out


def frozen_copy(net: _M) -> _M:
    """A copy of ``net`` that no optimiser trains (a slow critic, the published VAE)."""
    slow = copy.deepcopy(net)
    slow.requires_grad_(False)
    return slow
