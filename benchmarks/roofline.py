"""The compute floor of a learner update: its floating-point operations against the matrix
throughput of the device, both measured in the same process.

An update of the ``small`` preset at 512 imagination starts × 15 steps is mostly matrix
products (the critics' three MLPs over all 16 × 512 imagined states, forward, backward into the
actor's graph and backward into their weights). Counting its FLOPs (torch's
``FlopCounterMode``, matrix products only) and timing a matrix product of the update's own
shape gives ``ceiling_updates_per_s``: what the update could reach if every FLOP ran at that
product's speed and nothing else cost time. A target above the ceiling needs fewer FLOPs per
update (smaller or fewer networks, fewer states), not a faster implementation.

    .venv/bin/python benchmarks/roofline.py [--preset small] [--threads 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parent))

from learner import ACT, IMAG_STARTS, OBS, VAE_IN, D, _batch, _snapshot, measure

from ursa.learner import Learner
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.threads import limit_threads


def update_flops(cfg: LearnerConfig, obs: int, act: int, feat_in: int) -> dict[str, float]:
    """FLOPs of one ``train_step`` of ``cfg`` (matrix products, forward and backward), in total
    and by top-level network class (``Global`` is the total). Uses the synthetic batches of
    ``benchmarks/learner.py``."""
    rng = np.random.default_rng(0)
    learner = Learner(cfg, obs, act, feat_in)
    snap = _snapshot(learner, rng) if cfg.uses_skills else None
    batch = _batch(cfg, rng)
    learner.train_step(batch, snap)  # the first update allocates the optimisers' state
    with FlopCounterMode(display=False) as counter:
        learner.train_step(batch, snap)
    out: dict[str, float] = {}
    for name, by_op in counter.get_flop_counts().items():
        if "." not in name:  # top-level modules only (children are counted in their parent)
            out[name] = float(sum(by_op.values()))
    return out


def matmul_gflops(
    rows: int, inner: int, cols: int, dtype: torch.dtype = torch.float32, repeats: int = 7
) -> float:
    """GFLOP/s of ``(rows, inner) @ (inner, cols)`` on the CPU with the current torch threads
    (median of ``repeats`` timings of 10 products each)."""
    a = torch.randn(rows, inner, dtype=dtype)
    w = torch.randn(inner, cols, dtype=dtype)
    for _ in range(3):
        a @ w
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(10):
            a @ w
        rates.append(2.0 * rows * inner * cols * 10 / (time.perf_counter() - t0) / 1e9)
    return statistics.median(rates)


def critic_gemm_shape(cfg: LearnerConfig, skill_dim: int) -> tuple[int, int, int]:
    """(rows, inner, cols) of the first layer of a critic over every imagined state: the
    update's largest and most frequent product."""
    starts = cfg.imag_starts or cfg.batch_size * cfg.seq_len
    feat = cfg.deter + cfg.stoch * cfg.classes
    return (cfg.imag_horizon + 1) * starts, feat + skill_dim, cfg.units


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="small")
    ap.add_argument(
        "--threads", type=int, default=0, help="torch threads (0: URSA_TORCH_THREADS or 1)"
    )
    ap.add_argument("--updates", type=int, default=5, help="timed updates of the real update")
    ap.add_argument("--quick", action="store_true", help="2 timed updates")
    args = ap.parse_args()
    if args.quick:
        args.updates = 2
    limit_threads(torch_threads=args.threads or int(os.environ.get("URSA_TORCH_THREADS", "1")))
    base = learner_preset(args.preset, compute_dtype="float32")  # type: ignore[arg-type]
    cfg = dataclasses.replace(base, imag_starts=IMAG_STARTS)
    flops = update_flops(cfg, OBS, ACT, VAE_IN)
    total = flops.pop("Global")
    peak = matmul_gflops(*critic_gemm_shape(cfg, D))
    real = measure(cfg, args.updates, 1)["updates_per_s"]
    ceiling = peak * 1e9 / total
    threads = torch.get_num_threads()
    print(f"preset {args.preset}, float32, {IMAG_STARTS} starts x 15, {threads} thread(s)")
    # a network run from another's method (not its forward) counts under both names
    print(f"{'network':<16}{'GFLOP':>9}{'share':>8}  (by outermost network; may overlap)")
    for name, f in sorted(flops.items(), key=lambda kv: -kv[1]):
        print(f"{name:<16}{f / 1e9:>9.2f}{100 * f / total:>7.1f}%")
    print(f"{'total':<16}{total / 1e9:>9.2f}")
    print(f"matrix product {critic_gemm_shape(cfg, D)}: {peak:.1f} GFLOP/s")
    print(
        f"RESULT gflop_per_update={total / 1e9:.1f} matmul_gflops={peak:.1f} "
        f"ceiling_updates_per_s={ceiling:.3f} updates_per_s={real:.3f} "
        f"fraction_of_ceiling={real / ceiling:.2f}"
    )


if __name__ == "__main__":
    main()
