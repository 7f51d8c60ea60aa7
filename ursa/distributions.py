"""Small pure functions for the learner's distributions and losses (torch).

symlog/symexp squashing, two-hot codes over symexp-spaced bins, straight-through categorical
latents with a uniform mixture, their KL balancing with free nats, and a tanh-squashed Gaussian
for the actor. Shapes are in the docstrings; nothing here holds state.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def symlog(x: torch.Tensor) -> torch.Tensor:
    """sign(x) · log(1 + |x|), elementwise (any shape)."""
    return torch.sign(x) * torch.log1p(torch.abs(x))


def symexp(x: torch.Tensor) -> torch.Tensor:
    """sign(x) · (exp(|x|) − 1), the inverse of :func:`symlog` (any shape)."""
    return torch.sign(x) * torch.expm1(torch.abs(x))


def symexp_bins(n: int, limit: float = 20.0) -> torch.Tensor:
    """n bins (n,) ``symexp(linspace(−limit, limit, n))``, exactly symmetric around 0 (odd n
    puts a bin exactly at 0)."""
    g = torch.linspace(-limit, limit, n, dtype=torch.float64)
    return symexp(0.5 * (g - g.flip(0))).to(torch.float32)


def two_hot(x: torch.Tensor, bins: torch.Tensor) -> torch.Tensor:
    """Two-hot code (..., K) of values x (...) over increasing bins (K,).

    The weight is split linearly between the two bins around x so that ``code @ bins == x``
    for x inside the bin range; values outside are clipped to the end bins.
    """
    k = bins.shape[0]
    x = x.clamp(bins[0], bins[-1])
    hi = torch.searchsorted(bins, x.contiguous(), right=True).clamp(1, k - 1)
    lo = hi - 1
    b_lo, b_hi = bins[lo], bins[hi]
    w_hi = ((x - b_lo) / (b_hi - b_lo)).clamp(0.0, 1.0)
    code = torch.zeros(*x.shape, k, dtype=x.dtype, device=x.device)
    code.scatter_(-1, lo.unsqueeze(-1), (1.0 - w_hi).unsqueeze(-1))
    code.scatter_add_(-1, hi.unsqueeze(-1), w_hi.unsqueeze(-1))
    return code


def two_hot_mean(logits: torch.Tensor, bins: torch.Tensor) -> torch.Tensor:
    """Expected value (...) of the categorical with logits (..., K) over bins (K,)."""
    return torch.softmax(logits, -1) @ bins


def two_hot_loss(logits: torch.Tensor, target: torch.Tensor, bins: torch.Tensor) -> torch.Tensor:
    """Cross-entropy (...) of logits (..., K) against the two-hot code of target (...)."""
    return -(two_hot(target.detach(), bins) * F.log_softmax(logits, -1)).sum(-1)


def two_hot_loss2(
    logits: torch.Tensor,
    target: torch.Tensor,
    second: torch.Tensor,
    weight: float,
    bins: torch.Tensor,
) -> torch.Tensor:
    """``two_hot_loss(target) + weight · two_hot_loss(second)`` (...) with one log-softmax (the
    cross-entropy is linear in the target code)."""
    code = two_hot(target.detach(), bins) + weight * two_hot(second.detach(), bins)
    return -(code * F.log_softmax(logits, -1)).sum(-1)


def unimix_probs(logits: torch.Tensor, unimix: float) -> torch.Tensor:
    """Probabilities (..., K) ``(1 − unimix) · softmax(logits) + unimix / K``."""
    probs = torch.softmax(logits, -1)
    if unimix <= 0.0:
        return probs
    return probs * (1.0 - unimix) + unimix / logits.shape[-1]


def unimix_logits(logits: torch.Tensor, unimix: float) -> torch.Tensor:
    """Log-probabilities (..., K) of :func:`unimix_probs`."""
    if unimix <= 0.0:
        return F.log_softmax(logits, -1)
    return torch.log(unimix_probs(logits, unimix))


def sample_onehot_st(probs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """A one-hot sample (..., K) from probabilities (..., K) with straight-through gradients
    (the sample's gradient is the probabilities')."""
    u = torch.rand((*probs.shape[:-1], 1), generator=generator, device=probs.device)
    idx = (probs.detach().cumsum(-1) < u).sum(-1, keepdim=True).clamp_(max=probs.shape[-1] - 1)
    onehot = torch.zeros_like(probs).scatter_(-1, idx, 1.0)
    return onehot + (probs - probs.detach())


def categorical_kl(logp: torch.Tensor, logq: torch.Tensor) -> torch.Tensor:
    """KL(p ‖ q) (...) summed over the last two axes of log-probabilities (..., S, K)."""
    return (logp.exp() * (logp - logq)).sum((-2, -1))


def kl_balance(
    post_logp: torch.Tensor,
    prior_logp: torch.Tensor,
    free_nats: float,
    dyn_scale: float,
    rep_scale: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """DreamerV3's KL balancing on (..., S, K) log-probabilities.

    dyn = max(free, KL(sg(post) ‖ prior)) trains the prior; rep = max(free, KL(post ‖ sg(prior)))
    trains the encoder; both clipped per element (...) so that a KL under ``free_nats`` gives no
    gradient. Returns ``(loss, dyn, rep)``, each (...), loss = dyn_scale·dyn + rep_scale·rep.
    """
    dyn = categorical_kl(post_logp.detach(), prior_logp).clamp(min=free_nats)
    rep = categorical_kl(post_logp, prior_logp.detach()).clamp(min=free_nats)
    return dyn_scale * dyn + rep_scale * rep, dyn, rep


def tanh_normal_sample(
    mean: torch.Tensor, std: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised sample a = tanh(mean + std·ε) (..., A) and its log-density (...).

    The log-density includes the tanh Jacobian, so −log π(a) is an unbiased entropy estimate.
    """
    a, logp, _ = tanh_normal_rsample(mean, std, generator)
    return a, logp


def tanh_normal_rsample(
    mean: torch.Tensor, std: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`tanh_normal_sample` that also returns the pre-tanh sample u (..., A), which
    :func:`tanh_normal_logp` scores later (REINFORCE)."""
    eps = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
    u = mean + std * eps
    a = torch.tanh(u)
    logp_u = (-0.5 * eps.pow(2) - torch.log(std) - 0.5 * math.log(2.0 * math.pi)).sum(-1)
    # log(1 − tanh²(u)) = 2·(log 2 − u − softplus(−2u)), stable for large |u|
    log_det = (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
    return a, logp_u - log_det, u


def tanh_normal_logp(mean: torch.Tensor, std: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Log-density (...) of the action a = tanh(u) under tanh(N(mean, std²)), for a fixed
    pre-tanh sample u (..., A): differentiable in mean and std (the score function), while
    :func:`tanh_normal_sample`'s log-density is of a reparameterised sample."""
    u = u.detach()
    z = (u - mean) / std
    logp_u = (-0.5 * z.pow(2) - torch.log(std) - 0.5 * math.log(2.0 * math.pi)).sum(-1)
    log_det = (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
    return logp_u - log_det


def normal_entropy(std: torch.Tensor) -> torch.Tensor:
    """Entropy (...) of the pre-tanh Gaussian N(·, diag std²) (..., A): Σ log std + A/2·log 2πe."""
    return (torch.log(std) + 0.5 * math.log(2.0 * math.pi * math.e)).sum(-1)
