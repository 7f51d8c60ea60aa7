"""benchmarks/reference_dreamerv3.py: sheeprl's DreamerV3 (the optional extra ``reference``) is
built at the sizes asked, read back from its modules, and one timed update of it runs."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch

from ursa.learner_config import LearnerConfig

pytest.importorskip("sheeprl", reason="the optional extra: pip install -e '.[reference]'")

PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "reference_dreamerv3.py"

# every size different from the others and from sheeprl's defaults, so that a size passed to
# the wrong field (or not passed) shows in the sizes read back
TINY = LearnerConfig.tiny(
    deter=40,
    hidden=24,
    stoch=4,
    classes=5,
    units=16,
    layers=3,
    bins=17,
    batch_size=4,
    seq_len=8,
    imag_horizon=3,
)


def _load() -> ModuleType:
    """The benchmark module (``benchmarks/`` is scripts, not a package)."""
    name = "reference_dreamerv3"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, PATH)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # before exec: its dataclass looks its module up
        spec.loader.exec_module(module)
    return sys.modules[name]


def test_sizes_read_back_equal_the_sizes_asked() -> None:
    ref = _load()
    sizes = ref.ReferenceAgent.build(TINY, "cpu").sizes()
    want = ref.expected_sizes(TINY)
    assert {k: sizes[k] for k in want} == want
    assert sizes["params_critic"] == sizes["params_target_critic"] > 0
    assert sizes["params_world_model"] > sizes["params_actor"] > 0
    # the read-back is the modules', not the config's: another config's sizes don't match
    other = ref.expected_sizes(dataclasses.replace(TINY, deter=TINY.hidden, hidden=TINY.deter))
    assert {k: sizes[k] for k in other} != other


def test_one_timed_update_trains_every_part() -> None:
    ref = _load()
    threads = torch.get_num_threads()
    matmul = torch.get_float32_matmul_precision()
    agent = ref.ReferenceAgent.build(TINY, "cpu")
    parts = (agent.world_model, agent.actor, agent.critic)
    before = [[p.detach().clone() for p in m.parameters()] for m in parts]
    agent.train_step(ref.synthetic_batch(TINY, np.random.default_rng(0)))
    for m, old in zip(parts, before, strict=True):
        assert any(not torch.equal(p, q) for p, q in zip(m.parameters(), old, strict=True))

    r = ref.measure_reference(1, 0, "cpu", TINY)
    assert r["updates_per_s"] > 0 and math.isfinite(r["updates_per_s"])
    assert r["s_per_update"] == pytest.approx(1 / r["updates_per_s"])
    # the caller's process-wide settings are left as they were
    assert torch.get_num_threads() == threads
    assert torch.get_float32_matmul_precision() == matmul
