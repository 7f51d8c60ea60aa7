"""DreamerV3-style world model for vector observations, reset-free (paper §3.2, Alg. 2).

The RSSM has a deterministic GRU state h (``deter``) and ``stoch`` categorical latents of
``classes`` classes each (1% uniform mix, straight-through samples). Observations are symlog-ed
by the encoder; heads on the model state s = [h, z] predict the symlog observation (decoder,
MSE), the reward and the cost (two-hot over symexp bins) and the feature φ (symlog MSE). The
KL is balanced (dyn/rep) with free nats.

Time convention (one replay record per env step): record t holds ``obs`` after the step, the
``action`` that produced it and the ``reward``/``cost``/``features`` of that step. So
``h_t = GRU(h_{t−1}, z_{t−1}, action_t)`` and ``z_t ~ post(h_t, obs_t)``; every head at s_t
predicts the record's own values. There are no episodes: ``is_first`` (a gap in a collector's
stream, or the first record of a sampled sequence) re-initialises (h, z) to the learned initial
state before the step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from ursa.agent import whitened_sq
from ursa.distributions import (
    kl_balance,
    sample_onehot_st,
    symexp,
    symexp_bins,
    symlog,
    two_hot_loss,
    two_hot_mean,
    unimix_probs,
)
from ursa.learner_config import LearnerConfig
from ursa.networks import MLP, GRUCell, cast_input


class RSSM(nn.Module):
    """Recurrent state-space model with categorical latents."""

    def __init__(self, config: LearnerConfig, embed_dim: int, act_dim: int) -> None:
        super().__init__()
        c = config
        self.stoch, self.classes, self.deter, self.unimix = c.stoch, c.classes, c.deter, c.unimix
        self.act_dim = act_dim
        zdim = c.stoch * c.classes
        self.img_in = MLP(zdim + act_dim, 0, c.hidden, 1)
        self.gru = GRUCell(c.hidden, c.deter)
        self.prior = MLP(c.deter, zdim, c.hidden, 1)
        self.post = MLP(c.deter + embed_dim, zdim, c.hidden, 1)
        self.h0 = nn.Parameter(torch.zeros(c.deter))

    @property
    def feat_dim(self) -> int:
        """Size of the model state s = [h, z]."""
        return self.deter + self.stoch * self.classes

    def prior_probs(self, h: torch.Tensor) -> torch.Tensor:
        """(..., deter) -> prior probabilities (..., S, K) (with the uniform mix)."""
        return unimix_probs(self.prior(h).unflatten(-1, (self.stoch, self.classes)), self.unimix)

    def post_probs(self, h: torch.Tensor, embed: torch.Tensor) -> torch.Tensor:
        """(..., deter), (..., E) -> posterior probabilities (..., S, K)."""
        logits = self.post(torch.cat([h, embed], -1))
        return unimix_probs(logits.unflatten(-1, (self.stoch, self.classes)), self.unimix)

    def initial(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Learned initial state: h (B, deter) = tanh(h0), z (B, S·K) = the prior's probs."""
        h = torch.tanh(self.h0).expand(batch, -1)
        return h, self.prior_probs(h).flatten(-2)

    def core(self, h: torch.Tensor, z: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """h_{t−1} (B, deter), z_{t−1} (B, S·K), action_t (B, A) -> h_t (B, deter)."""
        return self.gru(self.img_in(torch.cat([z, action], -1)), h)

    def sample(self, probs: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """Straight-through one-hot sample (..., S·K) of probabilities (..., S, K)."""
        return sample_onehot_st(probs, generator).flatten(-2)

    def observe(
        self,
        embed: torch.Tensor,
        action: torch.Tensor,
        is_first: torch.Tensor,
        generator: torch.Generator | None,
    ) -> dict[str, torch.Tensor]:
        """Filter a batch of sequences.

        embed (B, T, E), action (B, T, A), is_first (B, T) bool. The state is initialised at
        t = 0 and wherever ``is_first``. Returns h (B, T, deter), z (B, T, S·K) and the
        posterior and prior log-probabilities ``post``, ``prior`` (B, T, S, K).
        """
        b, t_len = embed.shape[:2]
        h0, z0 = self.initial(b)
        h, z = h0, z0
        hs, zs, posts = [], [], []
        # one host sync up front instead of masking every step (gaps are rare)
        resets = is_first.any(0).tolist()
        for t in range(t_len):
            if t > 0 and resets[t]:
                m = is_first[:, t : t + 1].to(h.dtype)
                h = m * h0 + (1.0 - m) * h
                z = m * z0 + (1.0 - m) * z
            h = self.core(h, z, action[:, t])
            post = self.post_probs(h, embed[:, t])
            z = self.sample(post, generator)
            hs.append(h)
            zs.append(z)
            posts.append(post)
        hh = torch.stack(hs, 1)
        return {
            "h": hh,
            "z": torch.stack(zs, 1),
            "post": torch.log(torch.stack(posts, 1)),
            "prior": torch.log(self.prior_probs(hh)),
        }

    def img_step(
        self,
        h: torch.Tensor,
        z: torch.Tensor,
        action: torch.Tensor,
        generator: torch.Generator | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One imagined step: (h, z, a) -> (h', z' ~ prior(h'))."""
        h = self.core(h, z, action)
        return h, self.sample(self.prior_probs(h), generator)

    def obs_step(
        self,
        h: torch.Tensor,
        z: torch.Tensor,
        action: torch.Tensor,
        embed: torch.Tensor,
        generator: torch.Generator | None,
        sample: bool = True,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One filtering step: (h, z, a, embed) -> (h', z' ~ post(h', embed)); the posterior
        mode instead of a sample when ``sample`` is False."""
        h = self.core(h, z, action)
        post = self.post_probs(h, embed)
        if sample:
            return h, self.sample(post, generator)
        idx = post.argmax(-1, keepdim=True)
        return h, torch.zeros_like(post).scatter_(-1, idx, 1.0).flatten(-2)


class Encoder(nn.Module):
    """symlog(obs) -> embedding (..., units)."""

    def __init__(self, config: LearnerConfig, obs_dim: int) -> None:
        super().__init__()
        self.mlp = MLP(obs_dim, 0, config.units, config.layers)
        self.out_dim = self.mlp.out_dim

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """(..., obs_dim) -> (..., units)."""
        return self.mlp(symlog(obs))


@dataclass
class Imagined:
    """An imagined rollout from N start states: ``feat`` (H+1, N, F) the model states s_0..s_H,
    ``action`` (H, N, A), ``logp`` (H, N) and pre-tanh samples ``pre`` (H, N, A) of the actions
    taken at s_0..s_{H−1}."""

    feat: torch.Tensor
    action: torch.Tensor
    logp: torch.Tensor
    pre: torch.Tensor


class WorldModel(nn.Module):
    """Encoder + RSSM + heads (decoder, reward, cost, φ)."""

    bins: torch.Tensor

    def __init__(
        self,
        config: LearnerConfig,
        obs_dim: int,
        act_dim: int,
        phi_dim: int,
        cost_head: bool,
    ) -> None:
        super().__init__()
        c = config
        self.config = c
        self.encoder = Encoder(c, obs_dim)
        self.rssm = RSSM(c, self.encoder.out_dim, act_dim)
        f = self.rssm.feat_dim
        self.decoder = MLP(f, obs_dim, c.units, c.layers)
        self.reward = MLP(f, c.bins, c.units, c.layers, zero_out=True)
        self.cost: MLP | None = (
            MLP(f, c.bins, c.units, c.layers, zero_out=True) if cost_head else None
        )
        self.phi: MLP | None = MLP(f, phi_dim, c.units, c.layers) if phi_dim > 0 else None
        self.register_buffer("bins", symexp_bins(c.bins), persistent=False)

    @property
    def feat_dim(self) -> int:
        return self.rssm.feat_dim

    @staticmethod
    def feat(h: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Model state s = [h, z] (..., deter + S·K)."""
        return torch.cat([h, z], -1)

    def loss(
        self,
        data: dict[str, torch.Tensor],
        phi: torch.Tensor | None,
        generator: torch.Generator | None,
        phi_whiten: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """World-model loss on a batch.

        data: obs (B, T, O), action (B, T, A), reward (B, T), cost (B, T), is_first (B, T);
        phi: the feature targets (B, T, D) or None. ``phi_whiten`` A (D, D) with A Σ Aᵀ = I:
        the φ head's error is measured as ‖symexp(head) − φ‖²_Σ (the metric of δ) instead of
        the squared error of symlog(φ). Returns (loss, metrics (detached scalars), posterior
        states {h, z} (B, T, ·)).
        """
        c = self.config
        embed = self.encoder(data["obs"])
        post = self.rssm.observe(embed, data["action"], data["is_first"], generator)
        feat = self.feat(post["h"], post["z"])
        kl, dyn, rep = kl_balance(post["post"], post["prior"], c.free_nats, c.kl_dyn, c.kl_rep)
        dec = (self.decoder(feat) - symlog(data["obs"])).pow(2).sum(-1)
        rew = two_hot_loss(self.reward(feat), data["reward"], self.bins)
        loss = kl + dec + rew
        metrics = {
            "wm/dyn": dyn.mean(),
            "wm/rep": rep.mean(),
            "wm/decoder": dec.mean(),
            "wm/reward": rew.mean(),
        }
        if self.cost is not None:
            cost = two_hot_loss(self.cost(feat), data["cost"], self.bins)
            loss = loss + cost
            metrics["wm/cost"] = cost.mean()
        if self.phi is not None and phi is not None:
            if phi_whiten is None:
                phil = (self.phi(feat) - symlog(phi)).pow(2).sum(-1)
            else:
                phil = whitened_sq(symexp(self.phi(feat)) - phi, phi_whiten)
            loss = loss + phil
            metrics["wm/phi"] = phil.mean()
        loss = loss.mean()
        metrics["wm/loss"] = loss
        metrics = {k: v.detach() for k, v in metrics.items()}
        return loss, metrics, {"h": post["h"], "z": post["z"]}

    def predict(self, feat: torch.Tensor) -> dict[str, torch.Tensor]:
        """Head means at model states (..., F): reward (...), cost (...), phi (..., D)."""
        x = cast_input(feat)  # one cast for the three heads
        out = {"reward": two_hot_mean(self.reward(x), self.bins)}
        if self.cost is not None:
            out["cost"] = two_hot_mean(self.cost(x), self.bins)
        if self.phi is not None:
            out["phi"] = symexp(self.phi(x))
        return out

    def imagine(
        self,
        h: torch.Tensor,
        z: torch.Tensor,
        policy: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
        horizon: int,
        generator: torch.Generator | None,
    ) -> Imagined:
        """Roll the prior forward ``horizon`` steps from start states h (N, deter), z (N, S·K).

        ``policy(feat (N, F)) -> (action (N, A), logp (N,), pre-tanh (N, A))``; gradients flow
        through the dynamics (straight-through latents) back to the actions unless the caller
        runs it under ``torch.no_grad``.
        """
        feats = [self.feat(h, z)]
        actions, logps, pres = [], [], []
        for _ in range(horizon):
            a, logp, pre = policy(feats[-1])
            h, z = self.rssm.img_step(h, z, a, generator)
            feats.append(self.feat(h, z))
            actions.append(a)
            logps.append(logp)
            pres.append(pre)
        return Imagined(
            torch.stack(feats), torch.stack(actions), torch.stack(logps), torch.stack(pres)
        )
