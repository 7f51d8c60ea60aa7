"""Learner updates per second for the ``small`` and ``paper`` presets, split by phase.

Claims, each measured in the same run on the same device and thread count:
- the preset's update (``actor_grad="dynamics"``, ``compute_dtype="auto"``: bfloat16 layers on
  CPUs with AMX-BF16 or AVX512-BF16 and on GPUs) against the same update in float32, 512
  imagination starts × 15 steps at ``small`` sizes (``bf16_ratio``);
- the REINFORCE actor (``actor_grad="reinforce"``) does the same work per update as
  backpropagation through the dynamics in a fraction of the time (``dynamics_ratio``);
- one URSA update (world model + imagination with V, ψ, C, λ1, λ2 and the actor + VAE) costs a
  bounded multiple of the same learner in ``daydreamer`` mode (world model + reward-only
  actor-critic), with the time split between world model, imagination, actor, critics,
  multipliers and VAE;
- at ``small`` sizes, URSA's update against a maintained DreamerV3, sheeprl's (the optional
  extra ``reference``: ``pip install -e '.[reference]'``), built at the same sizes and timed on
  the same batches (``benchmarks/reference_dreamerv3.py`` says what differs between the two
  updates); without sheeprl the ratio is ``nan``.

Threads: the learner service's torch thread count (``--torch-threads``, env
``URSA_TORCH_THREADS``, 1 by default: torch's worker threads collapse when collectors hold the
cores) unless ``--threads`` says otherwise.

Inputs are synthetic but shaped like the A1 (obs 46, action 12, VAE input 13, D = 3) with a
repertoire snapshot of N_R = 5000 skills; no env is stepped, so this times the learner alone.

    .venv/bin/python benchmarks/learner.py            # small + paper, CUDA if available
    .venv/bin/python benchmarks/learner.py --quick    # < 60 s on a CPU
    .venv/bin/python benchmarks/learner.py --device cpu --presets small --updates 20

The last line is ``RESULT updates_per_s=<small, ursa mode, the preset's update, 512 starts>
... bf16_ratio=<preset ÷ float32> dynamics_ratio=<reinforce ÷ dynamics updates/s> ...
reference_ratio=<small ursa updates/s ÷ sheeprl DreamerV3 updates/s, nan without sheeprl>``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import numpy as np
import reference_dreamerv3 as reference  # benchmarks/reference_dreamerv3.py, beside this script
import torch

from ursa.learner import Learner, SkillSnapshot
from ursa.learner_config import LearnerConfig, learner_preset
from ursa.networks import dtype_name, resolve_compute_dtype
from ursa.repertoire import Repertoire, RepertoireConfig
from ursa.threads import limit_threads

OBS, ACT = reference.OBS, reference.ACT  # the A1's sizes, one place for both learners
VAE_IN, D = 13, 3
IMAG_STARTS = 512
"""Imagination starts per update at every preset here (the issue's fixed work per update)."""
PHASES = ("wm", "imagination", "actor", "critics", "multipliers", "vae")
REF = "sheeprl-dv3"
"""The row of the reference learner, sheeprl's DreamerV3 at ``small`` sizes."""


def _batch(cfg: LearnerConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The reference's synthetic batch plus URSA's cost and feature inputs (same draws as
    before the reference existed: obs, action, reward, cost, features)."""
    b, t = cfg.batch_size, cfg.seq_len
    out = reference.synthetic_batch(cfg, rng)
    out["cost"] = rng.normal(size=(b, t)).astype(np.float32)
    out["features"] = rng.normal(size=(b, t, VAE_IN)).astype(np.float32)
    return out


def _snapshot(learner: Learner, rng: np.random.Generator) -> SkillSnapshot:
    inputs = rng.normal(size=(6000, VAE_IN))
    rep = Repertoire(RepertoireConfig(size=5000, dim=D, n_z=100, input_dim=VAE_IN))
    rep.commit_many(learner.encode(inputs), inputs)
    return SkillSnapshot.from_repertoire(rep)


def measure(cfg: LearnerConfig, updates: int, warmup: int) -> dict[str, float]:
    """Updates per second of ``cfg`` and the mean seconds per phase."""
    rng = np.random.default_rng(0)
    learner = Learner(cfg, OBS, ACT, VAE_IN)
    learner.profile = True  # synchronise around phases so the split is right on a GPU
    snap = _snapshot(learner, rng) if cfg.uses_skills else None
    batches = [_batch(cfg, rng) for _ in range(min(updates + warmup, 4))]
    for i in range(warmup):
        learner.train_step(batches[i % len(batches)], snap)
    if learner.device.type == "cuda":
        torch.cuda.synchronize(learner.device)
    phases = dict.fromkeys(PHASES, 0.0)
    start = time.perf_counter()
    for i in range(updates):
        m = learner.train_step(batches[i % len(batches)], snap)
        for p in PHASES:
            phases[p] += m[f"time/{p}"] / updates
    if learner.device.type == "cuda":
        torch.cuda.synchronize(learner.device)
    total = time.perf_counter() - start
    return {"updates_per_s": updates / total, "s_per_update": total / updates, **phases}


def _count(module: torch.nn.Module | None) -> int:
    return sum(p.numel() for p in module.parameters()) if module is not None else 0


def _sizes_line(cfg: LearnerConfig) -> str:
    """Both learners' sizes at ``cfg`` (URSA's from its config and modules, sheeprl's read back
    from its built modules) and whether the network sizes are equal."""
    ref = reference.reference_sizes(cfg, cfg.device)
    want = reference.expected_sizes(cfg, OBS, ACT)
    same = all(ref[k] == v for k, v in want.items())
    urs = Learner(dataclasses.replace(cfg, mode="ursa"), OBS, ACT, VAE_IN)
    critics = sum(p.numel() for p in urs.critics.online_parameters())
    return (
        f"sizes: sheeprl DreamerV3 read back: deter {ref['deter']}, hidden {ref['hidden']}, "
        f"stoch {ref['stoch']}x{ref['classes']}, MLPs {ref['layers']}x{ref['units']}, "
        f"bins {ref['bins']}, obs {ref['obs']}, action {ref['action']}: "
        + ("equal to URSA's\n" if same else f"DIFFERENT FROM URSA's {want}\n")
        + f"params: world model {ref['params_world_model']:,} (URSA {_count(urs.wm):,}), "
        f"actor {ref['params_actor']:,} (URSA {_count(urs.actor):,}), "
        f"critic {ref['params_critic']:,} (URSA V+psi+C {critics:,}, "
        f"multipliers {_count(urs.lam1) + _count(urs.lam2):,}, VAE {_count(urs.vae):,})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--presets", default="small,paper", help="comma-separated presets")
    ap.add_argument("--updates", type=int, default=0, help="timed updates (0: by preset)")
    ap.add_argument(
        "--threads",
        type=int,
        default=0,
        help="torch CPU threads (0: the learner service's, URSA_TORCH_THREADS or 1)",
    )
    ap.add_argument(
        "--repeats",
        type=int,
        default=0,
        help="interleaved repeats of each measurement (median reported; 0: 3 quick)",
    )
    ap.add_argument("--quick", action="store_true", help="few updates, < 60 s on a CPU")
    args = ap.parse_args()
    # the pools a learner service sets (services.common.cli.serve), with its torch threads
    limit_threads(torch_threads=args.threads or int(os.environ.get("URSA_TORCH_THREADS", "1")))
    repeats = args.repeats or 3
    cuda = args.device.startswith("cuda")
    with_ref = reference.available()
    ref_note = ""
    rows = []
    for name in args.presets.split(","):
        base = learner_preset(name, device=args.device)  # type: ignore[arg-type]
        if args.updates:
            n = args.updates
        elif args.quick:
            n = 3 if name == "small" or cuda else 1
        else:
            n = 50 if name == "small" or cuda else 5
        warm = 1 if args.quick else 3
        dt = base.compute_dtype
        # (label, mode, actor gradient, compute dtype); the first is the preset's own update
        variants = [
            ("ursa", "ursa", "dynamics", dt),
            ("ursa-fp32", "ursa", "dynamics", "float32"),
            ("ursa-reinforce", "ursa", "reinforce", dt),
            ("daydreamer", "daydreamer", "dynamics", dt),
        ]
        if args.quick and name != "small" and not cuda:
            variants = variants[:1]  # the CPU quick run keeps the paper preset to one update
        # the reference imagines from every posterior state (B·T): 512 at small sizes
        ref_here = with_ref and name == "small" and base.batch_size * base.seq_len == IMAG_STARTS
        if ref_here:
            ref_note = _sizes_line(base)
        runs: dict[str, list[dict[str, float]]] = {v[0]: [] for v in variants}
        if ref_here:
            runs[REF] = []
        for _ in range(repeats if name == "small" or cuda else 1):
            for label, mode, grad, dtype in variants:  # interleaved: load hits every side alike
                cfg = dataclasses.replace(
                    base,
                    mode=mode,  # type: ignore[arg-type]
                    actor_grad=grad,  # type: ignore[arg-type]
                    compute_dtype=dtype,
                    imag_starts=IMAG_STARTS,
                )
                r = measure(cfg, n, warm)
                runs[label].append(r)
                print(f"measured {name}/{label}: {r['updates_per_s']:.3f} updates/s", flush=True)
            if ref_here:
                r = reference.measure_reference(n, warm, args.device, config=base)
                runs[REF].append(r)
                print(f"measured {name}/{REF}: {r['updates_per_s']:.3f} updates/s", flush=True)
        for label, rs in runs.items():
            best = sorted(rs, key=lambda r: r["updates_per_s"])[len(rs) // 2]  # the median
            rows.append((name, label, best))

    print(
        f"\ndevice: {args.device}, torch threads: {torch.get_num_threads()}, "
        f"imagination: {IMAG_STARTS} starts x 15 steps, median of {repeats}"
    )
    head = f"{'preset':<7} {'mode':<13} {'upd/s':>8} {'s/upd':>8} " + " ".join(
        f"{p[:11]:>11}" for p in PHASES
    )
    print(head)
    print("-" * len(head))
    for name, mode, r in rows:
        split = " ".join(
            f"{100 * r[p] / r['s_per_update']:>10.1f}%" if p in r else f"{'-':>11}" for p in PHASES
        )
        print(f"{name:<7} {mode:<13} {r['updates_per_s']:>8.3f} {r['s_per_update']:>8.3f} {split}")
    res = {(n, m): r for n, m, r in rows}
    out = []
    for name in args.presets.split(","):
        u, d = res.get((name, "ursa")), res.get((name, "daydreamer"))
        if u and d:
            ratio = d["updates_per_s"] / u["updates_per_s"]
            print(f"{name}: an URSA update costs {ratio:.2f}x a DayDreamer update (reference)")
            out.append(f"{name}_cost_vs_daydreamer={ratio:.2f}")
        if u:
            wm_share = u["wm"] / u["s_per_update"]
            print(f"{name}: world model {100 * wm_share:.0f}% of an URSA update")
            out.append(f"{name}_updates_per_s={u['updates_per_s']:.3f}")
        f32 = res.get((name, "ursa-fp32"))
        if u and f32:
            ratio = u["updates_per_s"] / f32["updates_per_s"]
            print(f"{name}: the preset's compute dtype runs {ratio:.2f}x the float32 updates/s")
            out.append(f"{name}_bf16_ratio={ratio:.2f}")
        rf = res.get((name, "ursa-reinforce"))
        if u and rf:
            ratio = rf["updates_per_s"] / u["updates_per_s"]
            print(
                f"{name}: the REINFORCE update runs {ratio:.2f}x the updates/s of "
                f"backpropagation through the dynamics"
            )
            out.append(f"{name}_dynamics_ratio={ratio:.2f}")
    small = res.get(("small", "ursa"))
    ref = res.get(("small", REF))
    if ref_note:
        print(ref_note)
    if small and ref:
        day = res.get(("small", "daydreamer"))
        ratio = small["updates_per_s"] / ref["updates_per_s"]
        print(
            f"small: URSA's update runs {ratio:.2f}x the updates/s of sheeprl's DreamerV3 "
            "at equal sizes (reference)"
        )
        if day:
            print(
                f"small: URSA's daydreamer-mode update (reward only, no VAE) runs "
                f"{day['updates_per_s'] / ref['updates_per_s']:.2f}x the updates/s of sheeprl's "
                "DreamerV3"
            )
        reference_ratio = f"reference_ratio={ratio:.3f}"
    else:
        if not with_ref:
            print(
                "reference: sheeprl is not installed; `pip install -e '.[reference]'` adds "
                "sheeprl's DreamerV3 at equal sizes (small preset)"
            )
        reference_ratio = "reference_ratio=nan"
    first = f"updates_per_s={small['updates_per_s']:.3f}" if small else "updates_per_s=nan"
    small_dtype = resolve_compute_dtype(
        learner_preset("small").compute_dtype, torch.device(args.device)
    )
    compute = dtype_name(small_dtype)
    print(
        "RESULT "
        + " ".join([first, *out, f"device={args.device}", f"compute={compute}", reference_ratio])
    )


if __name__ == "__main__":
    main()
