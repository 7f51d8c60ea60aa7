"""The networks' compute dtype (``LearnerConfig.compute_dtype``): bfloat16 layers return float32,
stay close to float32, really run in bfloat16, train, and resume bit for bit; ``auto`` follows the
CPU's flags and a measured bf16 product."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.ursa.learner.test_learner import MICRO, _random_replay, _snapshot
from ursa import networks
from ursa.learner import Learner
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.networks import (
    MLP,
    GRUCell,
    cast_input,
    compute_dtype,
    cpu_has_bf16,
    resolve_compute_dtype,
    weight_casts_cached,
)

torch.set_num_threads(1)

FLAGS_AMX = "processor\t: 0\nflags\t\t: fpu avx512f amx_bf16 amx_tile\n"
FLAGS_AVX512_BF16 = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16 avx512_vnni\n"
FLAGS_NO_BF16 = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16x amx_bf16x\n"


def test_cpu_flags_and_auto() -> None:
    assert cpu_has_bf16(FLAGS_AMX)
    assert cpu_has_bf16(FLAGS_AVX512_BF16)  # AMD Zen 4: bf16 dot products without AMX
    # AVX-512 without its bf16 instructions, and longer flags that contain the names, do not count
    assert not cpu_has_bf16(FLAGS_NO_BF16)
    assert not cpu_has_bf16("model name\t: amx_bf16 in a name, not a flag\n")
    cpu = torch.device("cpu")
    assert resolve_compute_dtype("float32", cpu) is None
    assert resolve_compute_dtype("bfloat16", cpu) is torch.bfloat16
    # auto on this CPU: what the flags and the measured product (once per process) say
    expected = torch.bfloat16 if networks._cpu_prefers_bf16() else None
    assert resolve_compute_dtype("auto", cpu) is expected
    if not cpu_has_bf16():
        assert expected is None
    with pytest.raises(ValueError):
        resolve_compute_dtype("float16", cpu)
    with pytest.raises(ValueError):
        LearnerConfig(compute_dtype="float16")  # type: ignore[arg-type]
    # the CPU and GPU presets pick by device; the tests' sizes stay float32 (bf16 is slower there)
    assert learner_preset("small").compute_dtype == learner_preset("paper").compute_dtype == "auto"
    for name in ("tiny", "point"):
        assert learner_preset(name).compute_dtype == "float32"  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("flags", "speedup", "expected"),
    [
        (True, 1.9, torch.bfloat16),  # AMX or AMD Zen 4: bf16 products about twice as fast
        (True, 1.25, torch.bfloat16),  # at the threshold
        (True, 1.2, None),  # below it
        (True, 0.53, None),  # AVX512-BF16 in the flags, slower products (an Intel VM, measured)
    ],
)
def test_auto_on_cpu_follows_the_measured_speedup(
    monkeypatch: pytest.MonkeyPatch, flags: bool, speedup: float, expected: torch.dtype | None
) -> None:
    assert networks.BF16_MIN_SPEEDUP == 1.25
    monkeypatch.setattr(networks, "cpu_has_bf16", lambda cpuinfo=None: flags)
    monkeypatch.setattr(networks, "cpu_bf16_speedup", lambda repeats=5: speedup)
    networks._cpu_prefers_bf16.cache_clear()
    try:
        assert resolve_compute_dtype("auto", torch.device("cpu")) is expected
        assert resolve_compute_dtype("float32", torch.device("cpu")) is None
        assert resolve_compute_dtype("bfloat16", torch.device("cpu")) is torch.bfloat16
    finally:
        networks._cpu_prefers_bf16.cache_clear()


def test_auto_without_bf16_flags_measures_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    def never(repeats: int = 5) -> float:
        raise AssertionError("emulated bf16 must not be timed")

    monkeypatch.setattr(networks, "cpu_has_bf16", lambda cpuinfo=None: False)
    monkeypatch.setattr(networks, "cpu_bf16_speedup", never)
    networks._cpu_prefers_bf16.cache_clear()
    try:
        assert resolve_compute_dtype("auto", torch.device("cpu")) is None
    finally:
        networks._cpu_prefers_bf16.cache_clear()


def test_dtype_names() -> None:
    assert networks.dtype_name(None) == "float32"
    assert networks.dtype_name(torch.bfloat16) == "bfloat16"


def test_bf16_speedup_is_a_ratio_of_real_timings() -> None:
    r = networks.cpu_bf16_speedup(repeats=3)
    assert math.isfinite(r) and 0.01 < r < 100.0


def test_bf16_layers_return_float32_close_to_float32() -> None:
    torch.manual_seed(0)
    mlp, gru = MLP(24, 7, 64, 2), GRUCell(24, 32)
    nn_init = torch.nn.init
    for p in mlp.head.parameters() if mlp.head is not None else ():
        nn_init.normal_(p, std=0.1)
    x, h = torch.randn(256, 24), torch.randn(256, 32).tanh()
    y32, g32 = mlp(x), gru(x, h)
    with compute_dtype(torch.bfloat16):
        y16, g16 = mlp(x), gru(x, h)
        assert cast_input(x).dtype is torch.bfloat16
    assert cast_input(x) is x  # float32 outside: unchanged
    assert y16.dtype is torch.float32 and g16.dtype is torch.float32
    # really computed in bfloat16 (8 bits of mantissa): not equal, but close
    assert not torch.equal(y16, y32) and not torch.equal(g16, g32)
    scale = float(y32.abs().max())
    assert float((y16 - y32).abs().max()) < 0.05 * scale
    assert float((g16 - g32).abs().max()) < 0.05
    # gradients reach the float32 weights
    with compute_dtype(torch.bfloat16):
        mlp(x).square().mean().backward()
    assert all(p.grad is not None and p.grad.dtype is torch.float32 for p in mlp.parameters())


def _learner(dtype: str, mode: str = "ursa-supervised") -> tuple[Learner, list, object]:
    cfg = dataclasses.replace(MICRO, mode=mode, compute_dtype=dtype)  # type: ignore[arg-type]
    replay = _random_replay()
    rng = np.random.default_rng(0)
    batches = [replay.sample(cfg.batch_size, cfg.seq_len, rng) for _ in range(6)]
    snap = _snapshot(rng.uniform(-1, 1, size=(300, 2)))
    return Learner(cfg, 6, 2, 2), batches, snap


def test_bf16_learner_trains_and_differs_from_float32() -> None:
    a, batches, snap = _learner("bfloat16")
    b, _, _ = _learner("float32")
    assert a.compute is torch.bfloat16 and b.compute is None
    ma = [a.train_step(x, snap) for x in batches[:4]]  # type: ignore[arg-type]
    mb = [b.train_step(x, snap) for x in batches[:4]]  # type: ignore[arg-type]
    assert all(math.isfinite(v) for m in ma for v in m.values())
    assert ma[-1]["wm/loss"] != mb[-1]["wm/loss"]  # the setting took effect
    assert ma[-1]["wm/loss"] == pytest.approx(mb[-1]["wm/loss"], rel=0.1)
    # the model's weights stay float32
    assert all(p.dtype is torch.float32 for p in a.wm.parameters())


def test_bf16_checkpoint_resumes_bit_for_bit(tmp_path: Path) -> None:
    a, batches, snap = _learner("bfloat16")
    for x in batches[:3]:
        a.train_step(x, snap)  # type: ignore[arg-type]
    a.save_checkpoint(tmp_path / "l.pt")
    cont = [a.train_step(x, snap) for x in batches[3:]]  # type: ignore[arg-type]
    other, _, _ = _learner("bfloat16")
    other.load_checkpoint(tmp_path / "l.pt")
    again = [other.train_step(x, snap) for x in batches[3:]]  # type: ignore[arg-type]
    for m1, m2 in zip(cont, again, strict=True):
        assert {k: v for k, v in m1.items() if not k.startswith("time/")} == {
            k: v for k, v in m2.items() if not k.startswith("time/")
        }


def test_weight_casts_cached_casts_each_weight_once_per_region() -> None:
    """Inside ``weight_casts_cached`` a weight's bfloat16 copy is made on its first use and
    reused: a weight changed in place afterwards is not seen (the documented caveat, and the
    proof that the cast is cached); outside, every call casts again. Under float32 it does
    nothing."""
    torch.manual_seed(0)
    cell = GRUCell(8, 16)
    x, h = torch.randn(4, 8), torch.randn(4, 16)
    cpu = torch.device("cpu")
    with compute_dtype(torch.bfloat16):
        with weight_casts_cached(cpu):
            first = cell(x, h)
            with torch.no_grad():
                cell.linear.weight.add_(
                    torch.randn_like(cell.linear.weight)
                )  # not a scale: LayerNorm follows
            stale = cell(x, h)
        fresh = cell(x, h)
        with weight_casts_cached(cpu):
            again = cell(x, h)
    assert torch.equal(first, stale)
    assert not torch.allclose(first, fresh)
    assert torch.equal(fresh, again)
    with weight_casts_cached(cpu):  # float32: no region, the change is seen at once
        a = cell(x, h)
        with torch.no_grad():
            cell.linear.weight.add_(torch.randn_like(cell.linear.weight))
        b = cell(x, h)
    assert not torch.allclose(a, b)
    assert a.dtype == b.dtype == torch.float32
