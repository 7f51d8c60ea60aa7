"""The learned feature function φ of URSA (paper §4.3): a VAE over the VAE inputs.

On the A1 the input is the joint angles and the base height (F = 13); in general any F-dim
vector. The latent has D dimensions (3 in the paper); φ(x) is the posterior *mean*, a
deterministic function usable as the repertoire's ``reencode`` function. Inputs are
standardised with running statistics that belong to the encoder (so a published encoder
version carries them and always computes the same φ).

The learner trains the VAE on the repertoire's stored inputs and publishes a frozen copy
every ``vae_publish_every`` updates; ``version`` counts the publishes.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ursa.networks import MLP


class VAE(nn.Module):
    """Gaussian VAE with a standard-normal prior and a unit-variance Gaussian decoder."""

    mean: torch.Tensor
    var: torch.Tensor
    count: torch.Tensor

    def __init__(self, input_dim: int, latent_dim: int, units: int, layers: int) -> None:
        super().__init__()
        self.input_dim, self.latent_dim = input_dim, latent_dim
        self.enc = MLP(input_dim, 2 * latent_dim, units, layers)
        self.dec = MLP(latent_dim, input_dim, units, layers)
        self.register_buffer("mean", torch.zeros(input_dim))
        self.register_buffer("var", torch.ones(input_dim))
        self.register_buffer("count", torch.zeros((), dtype=torch.long))

    def update_stats(self, x: torch.Tensor, rate: float = 0.01) -> None:
        """Fold a batch of inputs (N, F) into the standardisation statistics (first batch sets
        them, later batches move them by ``rate``)."""
        m, v = x.mean(0), x.var(0, unbiased=False)
        if int(self.count) == 0:
            self.mean.copy_(m)
            self.var.copy_(v)
        else:
            self.mean.mul_(1.0 - rate).add_(rate * m)
            self.var.mul_(1.0 - rate).add_(rate * v)
        self.count.add_(1)

    def _normalise(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / torch.sqrt(self.var + 1e-6)

    def posterior(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Inputs (..., F) -> posterior mean and std (..., D)."""
        mu, raw = self.enc(self._normalise(x)).chunk(2, -1)
        return mu, nn.functional.softplus(raw) + 1e-4

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """φ(x) = posterior mean (..., D) of inputs (..., F)."""
        return self.posterior(x)[0]

    def loss(
        self, x: torch.Tensor, beta: float, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Negative ELBO per input, averaged over the batch x (N, F): reconstruction (Gaussian,
        unit variance on standardised inputs) + beta · KL(q(z|x) ‖ N(0, I))."""
        mu, std = self.posterior(x)
        eps = torch.randn(mu.shape, generator=generator, device=mu.device, dtype=mu.dtype)
        rec = 0.5 * (self.dec(mu + std * eps) - self._normalise(x)).pow(2).sum(-1)
        kl = vae_kl_gaussian(mu, std)
        loss = (rec + beta * kl).mean()
        return loss, {"vae/rec": rec.mean().detach(), "vae/kl": kl.mean().detach()}

    @torch.no_grad()
    def encode(self, inputs: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """φ of inputs (M, F) as a float64 array (M, D): the repertoire's ``reencode`` function."""
        x = np.asarray(inputs, dtype=np.float32).reshape(-1, self.input_dim)
        dev = self.mean.device
        out = [
            self(torch.as_tensor(x[s : s + chunk], device=dev)).cpu().numpy()
            for s in range(0, len(x), chunk)
        ]
        if not out:
            return np.zeros((0, self.latent_dim))
        return np.concatenate(out).astype(np.float64)


def vae_kl_gaussian(mu: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, std²) ‖ N(0, I)) (...) summed over the last axis of (..., D)."""
    return 0.5 * (mu.pow(2) + std.pow(2) - 1.0 - 2.0 * torch.log(std)).sum(-1)
