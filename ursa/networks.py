"""Building blocks of the learner's networks: LayerNorm-SiLU MLPs and a LayerNorm GRU cell."""

from __future__ import annotations

import torch
from torch import nn


class MLP(nn.Module):
    """``layers`` × (Linear → LayerNorm → SiLU), then a Linear to ``out`` (or nothing if out=0).

    ``zero_out`` initialises the output layer to zero (DreamerV3 does so for the reward and
    value heads, so that their first predictions are 0 instead of noise).
    """

    def __init__(self, inp: int, out: int, units: int, layers: int, zero_out: bool = False) -> None:
        super().__init__()
        mods: list[nn.Module] = []
        d = inp
        for _ in range(layers):
            mods += [nn.Linear(d, units, bias=False), nn.LayerNorm(units, eps=1e-3), nn.SiLU()]
            d = units
        self.trunk = nn.Sequential(*mods)
        self.out_dim = out if out > 0 else d
        self.head: nn.Linear | None = nn.Linear(d, out) if out > 0 else None
        if self.head is not None and zero_out:
            nn.init.zeros_(self.head.weight)
            nn.init.zeros_(self.head.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(..., inp) -> (..., out)."""
        x = self.trunk(x)
        return self.head(x) if self.head is not None else x


class GRUCell(nn.Module):
    """DreamerV3's GRU: one Linear over [x, h] with LayerNorm, update gate biased to keep h."""

    def __init__(self, inp: int, size: int) -> None:
        super().__init__()
        self.size = size
        self.linear = nn.Linear(inp + size, 3 * size, bias=False)
        self.norm = nn.LayerNorm(3 * size, eps=1e-3)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """x (B, inp), h (B, size) -> h' (B, size)."""
        parts = self.norm(self.linear(torch.cat([x, h], -1)))
        reset, cand, update = parts.split(self.size, -1)
        reset = torch.sigmoid(reset)
        cand = torch.tanh(reset * cand)
        update = torch.sigmoid(update - 1.0)
        return update * cand + (1.0 - update) * h
