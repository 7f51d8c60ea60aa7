"""Building blocks of the learner's networks: LayerNorm-SiLU MLPs and a LayerNorm GRU cell,
and the precision their matrix products run in (:func:`compute_dtype`)."""

from __future__ import annotations

import contextlib
import contextvars
import functools
import statistics
import time
from collections.abc import Iterator
from pathlib import Path

import torch
from torch import nn

_COMPUTE: contextvars.ContextVar[torch.dtype | None] = contextvars.ContextVar(
    "ursa_compute_dtype", default=None
)


@contextlib.contextmanager
def compute_dtype(dtype: torch.dtype | None) -> Iterator[None]:
    """Inside, the networks of this module run their layers in ``dtype`` (torch autocast, e.g.
    bfloat16) and return float32; None: float32 throughout. Weights, gradients' accumulation in
    the optimisers, losses and returns stay float32 whatever the setting (DreamerV3's
    ``compute_dtype``)."""
    token = _COMPUTE.set(dtype)
    try:
        yield
    finally:
        _COMPUTE.reset(token)


@contextlib.contextmanager
def weight_casts_cached(device: torch.device) -> Iterator[None]:
    """Inside, each weight is cast to the compute dtype once, on its first use, instead of at
    every layer call (torch autocast's cast cache lives until the outermost autocast region
    ends; each network call opens and closes its own, so without this outer, disabled region
    the recurrent cells recast their weights at every step: T observe and H imagine steps).
    A weight changed in place inside (an optimiser step) keeps its stale cast: no forward pass
    may read a weight after its step in the same region. No effect under float32."""
    dtype = _COMPUTE.get()
    if dtype is None:
        yield
        return
    with torch.autocast(device.type, dtype=dtype, enabled=False):
        yield


def _autocast(x: torch.Tensor) -> contextlib.AbstractContextManager[object]:
    dtype = _COMPUTE.get()
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(x.device.type, dtype=dtype)


def cast_input(x: torch.Tensor) -> torch.Tensor:
    """``x`` in the compute dtype (unchanged under float32): an input that several networks read
    is cast once instead of once per network."""
    dtype = _COMPUTE.get()
    return x if dtype is None else x.to(dtype)


BF16_CPU_FLAGS = ("amx_bf16", "avx512_bf16")
"""/proc/cpuinfo flags of bfloat16 dot products in hardware: Intel's AMX-BF16 tiles and the
AVX512-BF16 instructions (Intel Cooper Lake and later, AMD Zen 4 and later)."""


def cpu_has_bf16(cpuinfo: str | None = None) -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AMX-BF16 or AVX512-BF16), from the
    flags of /proc/cpuinfo (or the text given)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return False
    return any(
        line.startswith("flags") and not set(BF16_CPU_FLAGS).isdisjoint(line.split())
        for line in cpuinfo.splitlines()
    )


BF16_MIN_SPEEDUP = 1.25
"""``auto`` picks bfloat16 on a CPU with bf16 flags only if a matrix product of an update's shape
runs at least this many times faster in bf16 than in float32 (:func:`cpu_bf16_speedup`). The
flags alone do not say it: measured whole updates at ``small`` sizes (docs/learner.md) ran
1.69× float32 on an Intel Xeon with AMX and 1.92× on an AMD EPYC (Zen 4, AVX512-BF16), but
0.64–0.85× on an Intel Xeon whose VM exposes AVX512-BF16 without AMX, where the product itself
runs at 0.53× float32."""


def cpu_bf16_speedup(repeats: int = 5) -> float:
    """float32 seconds ÷ bfloat16 seconds of (2048 × 512) · (512 × 256) on this CPU with the
    current torch threads: median over ``repeats`` interleaved pairs of 3 products each (about
    0.1 s in all). > 1: bf16 is faster."""
    gen = torch.Generator().manual_seed(0)
    x32 = torch.randn(2048, 512, generator=gen)
    w32 = torch.randn(512, 256, generator=gen)
    pairs = {torch.float32: (x32, w32), torch.bfloat16: (x32.bfloat16(), w32.bfloat16())}
    for x, w in pairs.values():  # first calls pay for the kernels' set-up
        x @ w
    ratios = []
    for _ in range(repeats):
        took = {}
        for dtype, (x, w) in pairs.items():
            start = time.perf_counter()
            for _ in range(3):
                x @ w
            took[dtype] = time.perf_counter() - start
        ratios.append(took[torch.float32] / max(took[torch.bfloat16], 1e-9))
    return float(statistics.median(ratios))


@functools.cache
def _cpu_prefers_bf16() -> bool:
    return cpu_has_bf16() and cpu_bf16_speedup() >= BF16_MIN_SPEEDUP


def resolve_compute_dtype(name: str, device: torch.device) -> torch.dtype | None:
    """The autocast dtype of a ``compute_dtype`` setting on ``device`` (None: float32).

    ``auto`` picks bfloat16 where it is faster: CUDA devices with bf16 support, and CPUs with
    AMX-BF16 or AVX512-BF16 flags on which a bf16 matrix product measures at least
    :data:`BF16_MIN_SPEEDUP` × float32's (once per process); float32 elsewhere (without the
    flags bf16 is emulated, several times slower)."""
    if name == "float32":
        return None
    if name == "bfloat16":
        return torch.bfloat16
    if name != "auto":
        raise ValueError(f"unknown compute_dtype {name!r}")
    if device.type == "cuda":
        return torch.bfloat16 if torch.cuda.is_bf16_supported() else None
    return torch.bfloat16 if device.type == "cpu" and _cpu_prefers_bf16() else None


def dtype_name(dtype: torch.dtype | None) -> str:
    """The ``compute_dtype`` name of a resolved dtype (None: float32), for logs and tables."""
    return "float32" if dtype is None else str(dtype).removeprefix("torch.")


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
        with _autocast(x):
            x = self.trunk(x)
            return (self.head(x) if self.head is not None else x).float()


class GRUCell(nn.Module):
    """DreamerV3's GRU: one Linear over [x, h] with LayerNorm, update gate biased to keep h."""

    def __init__(self, inp: int, size: int) -> None:
        super().__init__()
        self.size = size
        self.linear = nn.Linear(inp + size, 3 * size, bias=False)
        self.norm = nn.LayerNorm(3 * size, eps=1e-3)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """x (B, inp), h (B, size) -> h' (B, size)."""
        with _autocast(x):
            parts = self.norm(self.linear(torch.cat([x, h], -1))).float()
        reset, cand, update = parts.split(self.size, -1)
        reset = torch.sigmoid(reset)
        cand = torch.tanh(reset * cand)
        update = torch.sigmoid(update - 1.0)
        return update * cand + (1.0 - update) * h
