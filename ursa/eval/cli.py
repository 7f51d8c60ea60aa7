"""``ursa eval <command> <run dir or checkpoint> [--out DIR] ...``: the paper's figures.

Commands (see docs/eval.md): ``diversity`` (Figure 4), ``damage`` (Figure 5), ``velocity``
(Figure 6), ``embedding`` (Figure 1), ``curves`` (training curves), ``all`` (every one that
applies to the run). Each writes PNG figures and the numbers behind them (JSON, CSV) into
``--out`` (default ``<run>/eval/``) and prints a one-line JSON summary.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ursa.eval import adapt as adapt_cli
from ursa.eval.common import jsonable
from ursa.rundir import RunDir


def _common(p: argparse.ArgumentParser, steps: bool = True) -> None:
    p.add_argument("--out", type=Path, default=None, help="output directory (default: <run>/eval)")
    p.add_argument("--seed", type=int, default=0, help="env and action-noise seed")
    if steps:
        p.add_argument(
            "--steps",
            type=int,
            default=None,
            help="T: env steps per skill (default: the run's skill period)",
        )
        p.add_argument(
            "--mode",
            dest="explore",
            action="store_false",
            help="take the policy's mode instead of sampling actions (the scoring "
            "rule of ursa.scoring samples)",
        )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ursa eval", description="Reproduce the URSA paper's figures from a run directory."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("diversity", help="Figure 4: coverage of the skills' mean joint angles")
    p.add_argument("run", help="run directory or checkpoint")
    p.add_argument("--baseline", default=None, help="run to compare with (e.g. daydreamer)")
    p.add_argument(
        "--skills",
        type=int,
        default=None,
        help="N_z most distinct skills to execute (default: the run's N_z; 0: all)",
    )
    p.add_argument("--bins", type=int, default=20, help="cells per joint (per axis)")
    p.add_argument(
        "--settle",
        type=int,
        default=None,
        help="first steps of each skill executed but not averaged (default: the "
        "scoring rule's, a fifth of the steps)",
    )
    _common(p)

    p = sub.add_parser("damage", help="Figure 5: returns with a frozen joint")
    p.add_argument("run", nargs="+", help="URSA run directories (or checkpoints)")
    p.add_argument("--baseline", nargs="*", default=[], help="baseline runs (daydreamer)")
    p.add_argument(
        "--scenarios",
        nargs="*",
        default=None,
        help="damage scenarios (default: all six; 'intact' for none)",
    )
    p.add_argument(
        "--skills",
        type=int,
        default=None,
        help="N_z most distinct skills tried per scenario (default: the run's N_z)",
    )
    p.add_argument("--trials", type=int, default=1, help="executions of a baseline policy")
    p.add_argument("--rescue", action="store_true", help="keep the env's rescue on")
    _common(p)

    p = sub.add_parser("velocity", help="Figure 6: velocity-tracking error over a target grid")
    p.add_argument("run", help="run directory (--core.feature velocity) or checkpoint")
    p.add_argument("--grid", type=int, default=7, help="targets per axis")
    p.add_argument(
        "--margin",
        type=float,
        default=0.0,
        help="widen the repertoire's bounding box by this fraction on each side",
    )
    p.add_argument(
        "--quantile",
        type=float,
        default=0.0,
        help="box from the q and 1-q quantiles of the skills (0: min and max)",
    )
    p.add_argument(
        "--settle",
        type=int,
        default=None,
        help="first steps of each target executed but not measured (default: the "
        "scoring rule's, a fifth of the steps)",
    )
    _common(p)

    p = sub.add_parser("embedding", help="Figure 1: 2-D embedding of state trajectories")
    p.add_argument("run", help="run directory or checkpoint")
    p.add_argument("--skills", type=int, default=10, help="distinct skills to execute")
    p.add_argument(
        "--method",
        choices=("auto", "umap", "pca"),
        default="auto",
        help="auto: UMAP if umap-learn is installed, else PCA",
    )
    _common(p)

    p = sub.add_parser("curves", help="training curves from <run>/metrics/*.jsonl")
    p.add_argument("run", help="run directory")
    p.add_argument(
        "--control-hz",
        type=float,
        default=None,
        help="env steps per second of robot time (default: the run's control rate)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=None,
        help="env steps over which rates are taken (default: 1/25 of the run)",
    )
    _common(p, steps=False)

    adapt_cli.add_parser(sub, _common)

    p = sub.add_parser("all", help="every evaluation that applies to the run")
    p.add_argument("run", help="run directory")
    p.add_argument("--baseline", default=None, help="baseline run (daydreamer)")
    p.add_argument("--skills", type=int, default=None, help="N_z (default: the run's)")
    _common(p)
    return parser


def _threads(n: int) -> None:
    import torch  # noqa: F401 - loaded first, so that its pool is set too

    from ursa.threads import limit_threads

    limit_threads(torch_threads=n)


def cmd_diversity(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.diversity import run_diversity, write_diversity
    from ursa.eval.loading import default_out, load_run

    run = load_run(a.run, seed=a.seed)
    base = load_run(a.baseline, seed=a.seed) if a.baseline else None
    res = run_diversity(
        run, base, a.skills, a.steps, a.bins, a.settle, a.seed, a.explore, not a.no_progress
    )
    out = default_out(a.run, a.out)
    s = write_diversity(res, out, a.bins)
    return {
        "command": "diversity",
        "out": out,
        "covered": {k: v["covered_cells"] for k, v in s["runs"].items()},
        "total_cells": s["runs"]["ursa"]["total_cells"],
        "ratio": s.get("ratio"),
    }


def cmd_damage(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.damage import run_damage, write_damage
    from ursa.eval.loading import default_out, load_run

    runs = [load_run(r, seed=a.seed) for r in a.run]
    bases = [load_run(r, seed=a.seed) for r in a.baseline]
    trials = run_damage(
        runs,
        bases,
        a.scenarios,
        a.skills,
        a.steps,
        a.trials,
        a.rescue,
        a.seed,
        a.explore,
        not a.no_progress,
    )
    out = default_out(a.run[0], a.out)
    steps = a.steps or runs[0].config.collector.skill_period
    n = a.skills if a.skills is not None else runs[0].config.repertoire.n_z
    s = write_damage(trials, out, steps, n, a.rescue)
    return {
        "command": "damage",
        "out": out,
        "median": {
            lab: {sc: v["median"] for sc, v in st.items()} for lab, st in s["stats"].items()
        },
    }


def cmd_velocity(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.loading import default_out, load_run
    from ursa.eval.velocity import run_velocity, write_velocity

    run = load_run(a.run, seed=a.seed)
    res = run_velocity(
        run, a.grid, a.steps, a.settle, a.margin, a.seed, a.explore, not a.no_progress, a.quantile
    )
    out = default_out(a.run, a.out)
    s = write_velocity(res, out)
    return {"command": "velocity", "out": out, "dims": s["dims"], "error_mean": s["error_mean"]}


def cmd_embedding(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.embedding import run_embedding, write_embedding
    from ursa.eval.loading import default_out, load_run

    run = load_run(a.run, seed=a.seed)
    r, emb, ids = run_embedding(
        run, a.skills, a.steps, a.method, a.seed, a.explore, not a.no_progress
    )
    out = default_out(a.run, a.out)
    s = write_embedding(run, r, emb, ids, out)
    return {"command": "embedding", "out": out, "method": s["method"], "skills": s["skills"]}


def cmd_curves(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.curves import write_curves
    from ursa.eval.loading import default_out, load_config, resolve_run_dir

    run_dir, _ = resolve_run_dir(a.run)
    if run_dir is None:
        raise FileNotFoundError("curves need a run directory (with metrics/)")
    hz = a.control_hz
    if hz is None:
        try:
            hz = float(load_config(run_dir).a1.control_hz)
        except FileNotFoundError:
            hz = 20.0
    out = default_out(a.run, a.out)
    s = write_curves(run_dir, out, hz, a.window)
    return {"command": "curves", "out": out, "env_steps": s["env_steps"], "final": s["final"]}


def cmd_all(a: argparse.Namespace) -> dict[str, Any]:
    from ursa.eval.loading import load_run, resolve_run_dir

    run = load_run(a.run, seed=a.seed)
    base = ["--baseline", a.baseline] if a.baseline else []
    common = [
        *(["--out", str(a.out)] if a.out else []),
        "--seed",
        str(a.seed),
        "--threads",
        str(a.threads),
        *(["--no-progress"] if a.no_progress else []),
    ]
    steps = ["--steps", str(a.steps)] if a.steps else []
    skills = ["--skills", str(a.skills)] if a.skills is not None else []
    todo: list[list[str]] = []
    run_dir, _ = resolve_run_dir(a.run)
    if run_dir is not None and RunDir(run_dir).metrics.is_dir():
        todo.append(["curves", a.run, *common])
    if run.policy is not None:
        todo.append(["embedding", a.run, *common, *steps])
        if run.uses_skills and run.repertoire is not None and len(run.repertoire) > 1:
            todo.append(["diversity", a.run, *base, *common, *steps, *skills])
            cfg = run.config
            if not cfg.learned_feature and cfg.skill_dim == 2:
                todo.append(["velocity", a.run, *common, *steps])
            if cfg.env == "a1" and a.baseline:
                todo.append(["damage", a.run, *base, *common, *steps, *skills])
    results = {}
    for argv in todo:
        results[argv[0]] = _dispatch(build_parser().parse_args(argv))
    return {"command": "all", "ran": list(results), "results": results}


COMMANDS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "diversity": cmd_diversity,
    "damage": cmd_damage,
    "velocity": cmd_velocity,
    "embedding": cmd_embedding,
    "curves": cmd_curves,
    "adapt": adapt_cli.command,
    "all": cmd_all,
}


def _dispatch(a: argparse.Namespace) -> dict[str, Any]:
    _threads(a.threads)
    return COMMANDS[a.command](a)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ursa eval``; returns the exit status."""
    parser = build_parser()
    a = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        result = _dispatch(a)
    except (FileNotFoundError, ValueError) as e:
        print(f"ursa eval {a.command}: {e}", file=sys.stderr)
        return 1
    print(json.dumps(jsonable(result)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
