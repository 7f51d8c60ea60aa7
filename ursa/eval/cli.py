"""``ursa eval <command> <run dir or checkpoint> [--out DIR] ...``: the paper's figures.

Commands (see docs/eval.md): ``diversity`` (Figure 4), ``damage`` (Figure 5), ``velocity``
(Figure 6), ``embedding`` (Figure 1), ``curves`` (training curves), ``adapt`` (damage adaptation,
docs/adapt.md), ``all`` (every one that applies to the run). Each writes PNG figures and the
numbers behind them (JSON, CSV) into ``--out`` (default ``<run>/eval/``) and prints a one-line
JSON summary.

The command line is built with tyro from one frozen dataclass per command (its field docstrings
are the help); the options every command takes live in :class:`EvalArgs`, those of the commands
that execute skills in :class:`RolloutArgs`. ``ursa eval`` is also a subcommand of the ``ursa``
command (``services/cli.py``), which parses :data:`EvalCommand` and calls :func:`execute`.
The modules behind the commands (torch, the envs) are imported when a command runs, so that
``ursa --help`` stays quick.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Union

import tyro

from ursa.adapt import ITEParams
from ursa.rundir import RunDir

DESCRIPTION = "Reproduce the URSA paper's figures from a run directory."


def _arg(default: str | None = None, metavar: str | None = None) -> Any:
    """tyro's settings of an option: what its default means (in its help) and its metavar."""
    hint = None if default is None else f"(default: {default})"
    return tyro.conf.arg(metavar=metavar, help_behavior_hint=hint)


Run = Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
"""The positional run argument: a run directory or a learner checkpoint."""
Runs = Annotated[tuple[str, ...], _arg("none", "RUN [RUN ...]")]
"""Runs to compare with (``--baseline A B``)."""
Scenarios = tuple[str, ...] | None


@tyro.conf.configure(tyro.conf.FlagCreatePairsOff)
@dataclass(frozen=True, kw_only=True)
class EvalArgs:
    """Options every ``ursa eval`` command takes (one flag per boolean: ``--no-progress``)."""

    command: ClassVar[str]
    """The subcommand's name (``ursa eval <command>``)."""

    out: Annotated[Path | None, _arg("<run>/eval", "DIR")] = None
    """output directory"""
    seed: int = 0
    """env and action-noise seed"""
    no_progress: bool = False
    """hide the progress bars"""
    threads: int = 1
    """torch CPU threads"""


@dataclass(frozen=True, kw_only=True)
class RolloutArgs(EvalArgs):
    """Options of the commands that execute skills."""

    steps: Annotated[int | None, _arg("the run's skill period", "T")] = None
    """T: env steps per skill"""
    mode: bool = False
    """take the policy's mode instead of sampling actions (ursa.scoring's rule samples)"""

    @property
    def explore(self) -> bool:
        """Sample actions (the default) rather than take the policy's mode."""
        return not self.mode


@dataclass(frozen=True, kw_only=True)
class DiversityArgs(RolloutArgs):
    """Figure 4: coverage of the skills' mean joint angles."""

    command: ClassVar[str] = "diversity"
    run: Run
    """run directory or checkpoint"""
    baseline: Annotated[str | None, _arg("none", "RUN")] = None
    """run to compare with (e.g. daydreamer)"""
    skills: Annotated[int | None, _arg("the run's N_z; 0: all", "N")] = None
    """N_z most distinct skills to execute"""
    bins: int = 20
    """cells per joint (per axis)"""
    settle: Annotated[int | None, _arg("the scoring rule's, a fifth of the steps", "S")] = None
    """first steps of each skill executed but not averaged"""
    no_random: bool = False
    """skip the floor: uniformly random actions executed as many times"""


@dataclass(frozen=True, kw_only=True)
class DamageArgs(RolloutArgs):
    """Figure 5: returns with a frozen joint."""

    command: ClassVar[str] = "damage"
    run: Annotated[
        tuple[str, ...],
        tyro.conf.Positional,
        tyro.conf.arg(metavar="RUN [RUN ...]", help_behavior_hint="(required)"),
    ]
    """URSA run directories (or checkpoints)"""
    baseline: Runs = ()
    """baseline runs (daydreamer)"""
    scenarios: Annotated[Scenarios, _arg("all six; 'intact' for none", "S [S ...]")] = None
    """damage scenarios"""
    skills: Annotated[int | None, _arg("the first run's N_z", "N")] = None
    """K: selection trials per scenario for every method (URSA: its K most distinct skills; a
    baseline: K executions of its policy)"""
    fresh: int = 3
    """fresh trials of the selected skill (or policy) whose mean return is the score"""
    rescue: bool = False
    """keep the env's rescue on"""


@dataclass(frozen=True, kw_only=True)
class VelocityArgs(RolloutArgs):
    """Figure 6: velocity-tracking error over a target grid."""

    command: ClassVar[str] = "velocity"
    run: Run
    """run directory (--core.feature velocity) or checkpoint"""
    grid: int = 7
    """targets per axis"""
    margin: float = 0.0
    """widen the grid's box by this fraction on each side"""
    quantile: float = 0.1
    """the grid spans the q to 1-q quantiles of its points (0: min and max)"""
    grid_from: Literal["achieved", "repertoire"] = "achieved"
    """the grid's points: the mean features of the N_z most distinct skills, executed first
    (achieved), or the repertoire's per-step entries (repertoire)"""
    skills: Annotated[int | None, _arg("the run's N_z", "N")] = None
    """distinct skills executed for the grid (grid_from achieved)"""
    any_task: bool = False
    """measure an A1 run of another task than posture (Figure 6 is §5.3's posture task)"""
    settle: Annotated[int | None, _arg("the scoring rule's, a fifth of the steps", "S")] = None
    """first steps of each target executed but not measured"""


@dataclass(frozen=True, kw_only=True)
class EmbeddingArgs(RolloutArgs):
    """Figure 1: 2-D embedding of state trajectories."""

    command: ClassVar[str] = "embedding"
    run: Run
    """run directory or checkpoint"""
    skills: int = 10
    """distinct skills to execute"""
    method: Literal["auto", "umap", "pca"] = "auto"
    """auto: UMAP if umap-learn is installed, else PCA"""


@dataclass(frozen=True, kw_only=True)
class CurvesArgs(EvalArgs):
    """Training curves from <run>/metrics/*.jsonl."""

    command: ClassVar[str] = "curves"
    run: Run
    """run directory"""
    control_hz: Annotated[float | None, _arg("the run's control rate", "HZ")] = None
    """env steps per second of robot time"""
    window: Annotated[float | None, _arg("1/25 of the run", "STEPS")] = None
    """env steps over which rates are taken"""


@dataclass(frozen=True, kw_only=True)
class AdaptArgs(RolloutArgs):
    """ITE damage adaptation vs random search and DayDreamer (docs/adapt.md)."""

    command: ClassVar[str] = "adapt"
    run: Run
    """URSA run directory (or checkpoint)"""
    baseline: Runs = ()
    """DayDreamer runs (no adaptation)"""
    scenarios: Annotated[Scenarios, _arg("the six presets (A1), intact (point)", "S [S ...]")] = (
        None
    )
    """damages: presets, 'intact', or frozen joints joined by '+' (0..11 or names: FL_lower)"""
    skills: Annotated[int | None, _arg("the run's N_z", "N")] = None
    """map size"""
    seeds: int = 5
    """adaptations per scenario and method"""
    budget: int = ITEParams.budget
    """most trials"""
    alpha: float = ITEParams.alpha
    """ITE stopping threshold"""
    kappa: float = ITEParams.kappa
    """UCB exploration weight"""
    length_scale: float = ITEParams.length_scale
    """Matérn ρ (skill std units)"""
    noise: float = ITEParams.noise
    """GP noise (map range² units)"""
    no_reference: bool = False
    """skip executing every skill on each damaged robot (no trials-to-90% numbers)"""
    rescue: bool = False
    """keep the env's rescue on"""


@dataclass(frozen=True, kw_only=True)
class AllArgs(RolloutArgs):
    """Every evaluation that applies to the run."""

    command: ClassVar[str] = "all"
    run: Run
    """run directory"""
    baseline: Annotated[str | None, _arg("none", "RUN")] = None
    """baseline run (daydreamer)"""
    skills: Annotated[int | None, _arg("the run's", "N")] = None
    """N_z"""


EvalCommand = Union[  # noqa: UP007 - subcommands are Annotated members of a Union
    Annotated[DiversityArgs, tyro.conf.subcommand(DiversityArgs.command)],
    Annotated[DamageArgs, tyro.conf.subcommand(DamageArgs.command)],
    Annotated[VelocityArgs, tyro.conf.subcommand(VelocityArgs.command)],
    Annotated[EmbeddingArgs, tyro.conf.subcommand(EmbeddingArgs.command)],
    Annotated[CurvesArgs, tyro.conf.subcommand(CurvesArgs.command)],
    Annotated[AdaptArgs, tyro.conf.subcommand(AdaptArgs.command)],
    Annotated[AllArgs, tyro.conf.subcommand(AllArgs.command)],
]
"""The subcommands of ``ursa eval``, for ``tyro.cli``."""


def _threads(n: int) -> None:
    import torch  # noqa: F401 - loaded first, so that its pool is set too

    from ursa.threads import limit_threads

    limit_threads(torch_threads=n)


def cmd_diversity(a: DiversityArgs) -> dict[str, Any]:
    from ursa.eval.diversity import run_diversity, write_diversity
    from ursa.eval.loading import default_out, load_run

    run = load_run(a.run, seed=a.seed)
    base = load_run(a.baseline, seed=a.seed) if a.baseline else None
    res = run_diversity(
        run,
        base,
        a.skills,
        a.steps,
        a.bins,
        a.settle,
        a.seed,
        a.explore,
        not a.no_progress,
        random=not a.no_random,
    )
    out = default_out(a.run, a.out)
    s = write_diversity(res, out, a.bins)
    return {
        "command": a.command,
        "out": out,
        "covered": {k: v["covered_cells"] for k, v in s["runs"].items()},
        "safe_covered": {k: v["safe_covered_cells"] for k, v in s["runs"].items()},
        "total_cells": s["runs"]["ursa"]["total_cells"],
        "ratio": s.get("ratio"),
        "safe_ratio": s.get("safe_ratio"),
    }


def cmd_damage(a: DamageArgs) -> dict[str, Any]:
    from ursa.eval.damage import run_damage, write_damage
    from ursa.eval.loading import default_out, load_run

    if not a.run:
        raise ValueError("give at least one run")
    runs = [load_run(r, seed=a.seed) for r in a.run]
    bases = [load_run(r, seed=a.seed) for r in a.baseline]
    trials = run_damage(
        runs,
        bases,
        None if a.scenarios is None else list(a.scenarios),
        a.skills,
        a.steps,
        a.fresh,
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
        "command": a.command,
        "out": out,
        "median": {
            lab: {sc: v["median"] for sc, v in st.items()} for lab, st in s["stats"].items()
        },
    }


def cmd_velocity(a: VelocityArgs) -> dict[str, Any]:
    from ursa.eval.loading import default_out, load_run
    from ursa.eval.velocity import run_velocity, write_velocity

    run = load_run(a.run, seed=a.seed)
    res = run_velocity(
        run,
        a.grid,
        a.steps,
        a.settle,
        a.margin,
        a.seed,
        a.explore,
        not a.no_progress,
        a.quantile,
        a.grid_from,
        a.skills,
        a.any_task,
    )
    out = default_out(a.run, a.out)
    s = write_velocity(res, out)
    return {"command": a.command, "out": out, "dims": s["dims"], "error_mean": s["error_mean"]}


def cmd_embedding(a: EmbeddingArgs) -> dict[str, Any]:
    from ursa.eval.embedding import run_embedding, write_embedding
    from ursa.eval.loading import default_out, load_run

    run = load_run(a.run, seed=a.seed)
    r, emb, ids = run_embedding(
        run, a.skills, a.steps, a.method, a.seed, a.explore, not a.no_progress
    )
    out = default_out(a.run, a.out)
    s = write_embedding(run, r, emb, ids, out)
    return {"command": a.command, "out": out, "method": s["method"], "skills": s["skills"]}


def cmd_curves(a: CurvesArgs) -> dict[str, Any]:
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
    return {"command": a.command, "out": out, "env_steps": s["env_steps"], "final": s["final"]}


def cmd_adapt(a: AdaptArgs) -> dict[str, Any]:
    from ursa.eval.adapt import run_adapt, write_adapt
    from ursa.eval.loading import default_out, load_run

    run = load_run(a.run, seed=a.seed)
    bases = [load_run(r, seed=a.seed) for r in a.baseline]
    params = ITEParams(
        alpha=a.alpha, kappa=a.kappa, budget=a.budget, length_scale=a.length_scale, noise=a.noise
    )
    res = run_adapt(
        run,
        bases,
        None if a.scenarios is None else list(a.scenarios),
        a.skills,
        a.steps,
        params,
        a.seeds,
        a.seed,
        not a.no_reference,
        a.rescue,
        a.explore,
        not a.no_progress,
    )
    out = default_out(a.run, a.out)
    write_adapt(res, out)
    return {"command": a.command, "out": out, "map_cached": res["map"]["cached"], **res["summary"]}


def cmd_all(a: AllArgs) -> dict[str, Any]:
    from ursa.eval.loading import load_run, resolve_run_dir

    run = load_run(a.run, seed=a.seed)
    # the options every command takes, and those of the ones that execute skills, as given
    shared: dict[str, Any] = {f.name: getattr(a, f.name) for f in dataclasses.fields(EvalArgs)}
    rollout: dict[str, Any] = {**shared, "steps": a.steps or None, "mode": a.mode}
    todo: list[EvalArgs] = []
    run_dir, _ = resolve_run_dir(a.run)
    if run_dir is not None and RunDir(run_dir).metrics.is_dir():
        todo.append(CurvesArgs(run=a.run, **shared))
    if run.policy is not None:
        todo.append(EmbeddingArgs(run=a.run, **rollout))
        if run.uses_skills and run.repertoire is not None and len(run.repertoire) > 1:
            todo.append(DiversityArgs(run=a.run, baseline=a.baseline, skills=a.skills, **rollout))
            cfg = run.config
            posture = cfg.env != "a1" or cfg.a1.task == "posture"  # Figure 6's task
            if not cfg.learned_feature and cfg.skill_dim == 2 and posture:
                todo.append(VelocityArgs(run=a.run, skills=a.skills, **rollout))
            if cfg.env == "a1" and a.baseline:
                todo.append(
                    DamageArgs(run=(a.run,), baseline=(a.baseline,), skills=a.skills, **rollout)
                )
    results = {cmd.command: run_command(cmd) for cmd in todo}
    return {"command": a.command, "ran": list(results), "results": results}


COMMANDS: dict[type[EvalArgs], Callable[[Any], dict[str, Any]]] = {
    DiversityArgs: cmd_diversity,
    DamageArgs: cmd_damage,
    VelocityArgs: cmd_velocity,
    EmbeddingArgs: cmd_embedding,
    CurvesArgs: cmd_curves,
    AdaptArgs: cmd_adapt,
    AllArgs: cmd_all,
}
"""The function that runs each command, by its arguments' class."""


def run_command(a: EvalArgs) -> dict[str, Any]:
    """Run one command (torch's threads set first); returns its summary."""
    _threads(a.threads)
    return COMMANDS[type(a)](a)


def execute(a: EvalArgs) -> int:
    """Run a parsed command and print its one-line JSON summary; returns the exit status (1 with
    a message on stderr when the run does not fit the command)."""
    from ursa.eval.common import jsonable

    try:
        result = run_command(a)
    except (FileNotFoundError, ValueError) as e:
        print(f"ursa eval {a.command}: {e}", file=sys.stderr)
        return 1
    print(json.dumps(jsonable(result)))
    return 0


def parse(argv: list[str] | None = None) -> EvalArgs:
    """The arguments of ``ursa eval`` (``sys.argv[1:]`` by default) as a command's dataclass;
    exits with status 2 and a message on a bad command line."""
    a: EvalArgs = tyro.cli(EvalCommand, args=argv, prog="ursa eval", description=DESCRIPTION)
    return a


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ursa eval``; returns the exit status."""
    return execute(parse(sys.argv[1:] if argv is None else argv))


if __name__ == "__main__":
    raise SystemExit(main())
