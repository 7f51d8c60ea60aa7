"""Pure-numpy inference of the collector's policy: the world model's filter and the actor.

A collector acts one observation at a time on a CPU, where torch's per-op overhead dominates the
few small matrix-vector products of a step. This module computes what the torch modules compute
(``ursa.networks.MLP``/``GRUCell``, ``ursa.world_model.Encoder``/``RSSM.obs_step`` and
``ursa.agent.Actor``), in float32 and equal to float rounding (tested to 1e-5), from weights
copied out of those modules by :func:`policy_params`. The latent sample is the torch sampler's
inverse CDF, so the same uniforms give the same one-hot latents. The functions are pure; they
accept any leading batch shape (``...``) though the policy calls them with single vectors.

Linear weights are stored transposed, (in, out), so that ``x @ w`` maps (..., in) to (..., out).
Three rearrangements keep the numpy calls per step few, all exact up to rounding: the weights of
a Linear followed by a LayerNorm are centred (see :class:`NormLinear`), the GRU's −1 update bias
and the actor's +2 std offset are folded into the following shift and bias.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.special import expit
from torch import nn

from ursa.agent import Actor
from ursa.networks import MLP, GRUCell
from ursa.world_model import RSSM, Encoder

F32 = np.float32


# ---- parameters --------------------------------------------------------------------------------
@dataclass(frozen=True)
class NormLinear:
    """A Linear without bias followed by a LayerNorm over its outputs.

    ``w`` (in, out) is the Linear's weight transposed and centred (each row minus its mean),
    so that ``x @ w`` is already the LayerNorm's ``y − mean(y)`` of the Linear's output y (the
    same numbers up to float rounding, one pass fewer). ``scale``, ``shift`` (out,) and ``eps``
    are the LayerNorm's.
    """

    w: np.ndarray
    scale: np.ndarray
    shift: np.ndarray
    eps: float


@dataclass(frozen=True)
class MLPParams:
    """An :class:`ursa.networks.MLP`: hidden layers (NormLinear → SiLU), then an optional head
    Linear ``head_w`` (in, out) with bias ``head_b`` (out,)."""

    trunk: tuple[NormLinear, ...]
    head_w: np.ndarray | None
    head_b: np.ndarray | None


@dataclass(frozen=True)
class GRUParams:
    """An :class:`ursa.networks.GRUCell`: one NormLinear ``gates`` (inp + size -> 3·size) over
    [x, h], split into reset, candidate and update parts (the update part's ``shift`` includes
    the gate's −1 bias towards keeping h); the state ``size``."""

    gates: NormLinear
    size: int


@dataclass(frozen=True)
class PolicyParams:
    """Everything :func:`filter_step` and :func:`actor_dist` need.

    ``h_init`` (deter,) and ``z_init`` (S·K,) are the RSSM's learned initial state;
    ``stoch`` S latents of ``classes`` K classes with a ``unimix`` uniform mix. The actor's head
    puts out the pre-tanh mean (A) and the std's logit (A), whose +2 offset is folded into
    ``actor.head_b``; the std lies in [``min_std``, ``max_std``].
    """

    encoder: MLPParams
    img_in: MLPParams
    gru: GRUParams
    post: MLPParams
    actor: MLPParams
    h_init: np.ndarray
    z_init: np.ndarray
    stoch: int
    classes: int
    unimix: float
    min_std: float
    max_std: float


# ---- extraction from the torch modules -----------------------------------------------------------
def _np(t: torch.Tensor) -> np.ndarray:
    """A float32 C-contiguous copy of a tensor (or parameter)."""
    return np.array(t.detach().to("cpu").numpy(), dtype=F32, order="C", copy=True)


def norm_linear_params(lin: nn.Module, norm: nn.Module) -> NormLinear:
    """A bias-free ``lin`` followed by an affine LayerNorm ``norm`` over its outputs."""
    if not isinstance(lin, nn.Linear) or lin.bias is not None:
        raise TypeError(f"expected a Linear without bias, got {lin}")
    if not isinstance(norm, nn.LayerNorm) or norm.normalized_shape != (lin.out_features,):
        raise TypeError(f"expected a LayerNorm over {lin.out_features} features, got {norm}")
    if norm.weight is None or norm.bias is None:
        raise TypeError("expected an affine LayerNorm")
    w = lin.weight.detach().to("cpu", torch.float64).T  # (in, out)
    w = w - w.mean(1, keepdim=True)
    return NormLinear(_np(w), _np(norm.weight), _np(norm.bias), float(norm.eps))


def mlp_params(m: MLP) -> MLPParams:
    """The weights of ``m`` (its trunk must be (Linear without bias, LayerNorm, SiLU) × n)."""
    mods = list(m.trunk)
    if len(mods) % 3 or not all(isinstance(a, nn.SiLU) for a in mods[2::3]):
        raise TypeError(f"unexpected MLP trunk {mods}")
    trunk = tuple(norm_linear_params(mods[i], mods[i + 1]) for i in range(0, len(mods), 3))
    if m.head is None:
        return MLPParams(trunk, None, None)
    if m.head.bias is None:
        raise TypeError("expected an MLP head with a bias")
    return MLPParams(trunk, _np(m.head.weight.T), _np(m.head.bias))


def gru_params(g: GRUCell) -> GRUParams:
    """The weights of ``g``."""
    gates = norm_linear_params(g.linear, g.norm)
    gates.shift[2 * g.size :] -= 1.0
    return GRUParams(gates, int(g.size))


def policy_params(encoder: Encoder, rssm: RSSM, actor: Actor) -> PolicyParams:
    """Copy the weights of the policy's torch modules (and the RSSM's initial state)."""
    with torch.inference_mode():
        h0, z0 = rssm.initial(1)
    actor_p = mlp_params(actor.mlp)
    assert actor_p.head_b is not None
    actor_p.head_b[actor.act_dim :] += 2.0
    return PolicyParams(
        encoder=mlp_params(encoder.mlp),
        img_in=mlp_params(rssm.img_in),
        gru=gru_params(rssm.gru),
        post=mlp_params(rssm.post),
        actor=actor_p,
        h_init=_np(h0[0]),
        z_init=_np(z0[0]),
        stoch=int(rssm.stoch),
        classes=int(rssm.classes),
        unimix=float(rssm.unimix),
        min_std=float(actor.min_std),
        max_std=float(actor.max_std),
    )


# ---- building blocks -----------------------------------------------------------------------------
# Single vectors (n,) are the hot path: ufunc calls on small arrays cost more than their
# arithmetic, so the functions below keep the number of numpy calls low (in-place updates,
# python-float scalars) and accept any leading batch shape (...) too.


def symlog(x: np.ndarray) -> np.ndarray:
    """sign(x) · log(1 + |x|), elementwise (any shape)."""
    return np.copysign(np.log1p(np.abs(x)), x)


def sigmoid(x: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(−x)), elementwise, without overflow (any shape)."""
    return expit(x)


def silu(x: np.ndarray) -> np.ndarray:
    """x · sigmoid(x), elementwise (any shape)."""
    y = expit(x)
    y *= x
    return y


def linear(x: np.ndarray, w: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """x (..., in) @ w (in, out) [+ b (out,)] -> (..., out)."""
    y = x @ w
    if b is not None:
        y += b
    return y


def layernorm_centred(
    d: np.ndarray, scale: np.ndarray, shift: np.ndarray, eps: float
) -> np.ndarray:
    """LayerNorm of zero-mean inputs d (..., n) over the last axis, in place:
    d / sqrt(mean(d²) + eps) · scale + shift (torch's biased variance)."""
    n = d.shape[-1]
    if d.ndim == 1:
        d *= 1.0 / math.sqrt(float(np.dot(d, d)) / n + eps)
    else:
        d *= 1.0 / np.sqrt(np.add.reduce(d * d, -1, keepdims=True) / n + eps)
    d *= scale
    d += shift
    return d


def norm_linear(x: np.ndarray, p: NormLinear) -> np.ndarray:
    """LayerNorm(Linear(x)): (..., in) -> (..., out)."""
    return layernorm_centred(x @ p.w, p.scale, p.shift, p.eps)


def mlp(x: np.ndarray, p: MLPParams) -> np.ndarray:
    """An MLP: (..., in) -> (..., out) (the last hidden size when there is no head)."""
    for layer in p.trunk:
        x = silu(norm_linear(x, layer))
    if p.head_w is not None:
        x = linear(x, p.head_w, p.head_b)
    return x


def gru_step(x: np.ndarray, h: np.ndarray, p: GRUParams) -> np.ndarray:
    """DreamerV3's LayerNorm GRU: x (..., inp), h (..., size) -> h' (..., size)."""
    parts = norm_linear(np.concatenate([x, h], -1), p.gates)
    n = p.size
    reset = sigmoid(parts[..., :n])
    reset *= parts[..., n : 2 * n]
    cand = np.tanh(reset, out=reset)
    update = sigmoid(parts[..., 2 * n :])  # the −1 is in the shift
    # update · cand + (1 − update) · h
    cand -= h
    cand *= update
    cand += h
    return cand


def softmax(x: np.ndarray) -> np.ndarray:
    """Softmax over the last axis (any shape)."""
    e = np.exp(x - np.maximum.reduce(x, -1, keepdims=True))
    e /= np.add.reduce(e, -1, keepdims=True)
    return e


def unimix_probs(logits: np.ndarray, unimix: float) -> np.ndarray:
    """Probabilities (..., K) ``(1 − unimix) · softmax(logits) + unimix / K``."""
    probs = softmax(logits)
    if unimix > 0.0:
        probs *= 1.0 - unimix
        probs += unimix / logits.shape[-1]
    return probs


def sample_onehot(probs: np.ndarray, u: np.ndarray) -> np.ndarray:
    """A one-hot sample (..., K) of probabilities (..., K) by inverse CDF with uniforms u (...)
    in [0, 1): the first class whose cumulative probability reaches u (the last class if
    rounding leaves the total under u). The cumulative sums are taken in float64 and
    rounded to float32, as torch's CPU cumsum does, so that the same u gives the same sample
    as the RSSM's torch sampler."""
    k = probs.shape[-1]
    cdf = np.add.accumulate(probs, -1, dtype=np.float64).astype(F32)
    idx = np.add.reduce(cdf < u[..., None], -1)
    np.minimum(idx, k - 1, out=idx)
    return _eye(k)[idx]


@functools.cache
def _eye(k: int) -> np.ndarray:
    """The identity (k, k), float32: its rows are the one-hot codes (read-only)."""
    e = np.eye(k, dtype=F32)
    e.flags.writeable = False
    return e


# ---- the policy's computations -------------------------------------------------------------------
def encode(obs: np.ndarray, p: PolicyParams) -> np.ndarray:
    """Encoder: observations (..., O) -> embeddings (..., E)."""
    return mlp(symlog(obs), p.encoder)


def core(h: np.ndarray, z: np.ndarray, action: np.ndarray, p: PolicyParams) -> np.ndarray:
    """RSSM.core: h_{t−1} (..., deter), z_{t−1} (..., S·K), action_t (..., A) -> h_t."""
    return gru_step(mlp(np.concatenate([z, action], -1), p.img_in), h, p.gru)


def post_probs(h: np.ndarray, embed: np.ndarray, p: PolicyParams) -> np.ndarray:
    """RSSM posterior: h (..., deter), embed (..., E) -> probabilities (..., S, K)."""
    logits = mlp(np.concatenate([h, embed], -1), p.post)
    return unimix_probs(logits.reshape(*logits.shape[:-1], p.stoch, p.classes), p.unimix)


def filter_step(
    h: np.ndarray,
    z: np.ndarray,
    action: np.ndarray,
    obs: np.ndarray,
    u: np.ndarray,
    p: PolicyParams,
) -> tuple[np.ndarray, np.ndarray]:
    """Encoder + RSSM.obs_step: (h (..., deter), z (..., S·K), action (..., A), obs (..., O))
    -> (h', z' (..., S·K)), z' the posterior sample drawn with uniforms u (..., S)."""
    h = core(h, z, action, p)
    probs = post_probs(h, encode(obs, p), p)
    z = sample_onehot(probs, u)
    return h, z.reshape(*z.shape[:-2], p.stoch * p.classes)


def actor_dist(
    h: np.ndarray, z: np.ndarray, skill: np.ndarray, p: PolicyParams
) -> tuple[np.ndarray, np.ndarray]:
    """Actor at the model state s = [h, z]: h (..., deter), z (..., S·K), skill (..., D) ->
    pre-tanh mean and std (..., A)."""
    out = mlp(np.concatenate([h, z, skill], -1), p.actor)
    a = out.shape[-1] // 2
    std = sigmoid(out[..., a:])  # the +2 is in the head's bias
    std *= p.max_std - p.min_std
    std += p.min_std
    return out[..., :a], std
