"""``ursa eval diversity``: coverage of the mean joint angles of the skills (paper Figure 4).

Each skill of the repertoire (or the N_z most distinct ones, picked by farthest-point sampling
in the Mahalanobis metric of δ) is executed by the policy for T steps in the real env, one after
the other without resets; its mean joint angles over the execution (the mean position on the
point env) are binned into a grid of cells per joint (one 2-D grid over the arena on the point
env). A cell is covered when at least one skill's mean falls in it. A baseline run (``--baseline``,
e.g. ``daydreamer``) is executed the same number of times: a policy without skills repeats its one
behaviour, so its count is what a single-skill learner covers. Uniformly random actions, executed
as many times (``random``), draw the floor.

Only safe executions count towards the coverage the figure compares (``safe_covered_cells``): an
execution with any unsafe step (a fall, or the posture task's limits crossed) reaches joint angles
the safe set excludes, so a policy that falls could cover more cells than one that stays safe.
``covered_cells`` counts every execution.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ursa import scoring
from ursa.eval.common import distinct_skills, pyplot, save_figure, write_csv, write_json
from ursa.eval.coverage import JOINT_TYPES, LEGS, Coverage, coverage, coverage_specs
from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import Rollouts, execute_skills, skill_distance


@dataclass
class DiversityRun:
    """One run's executions and their coverage."""

    label: str
    run: LoadedRun
    rollouts: Rollouts
    key: str
    coverage: Coverage
    skill_ids: np.ndarray
    safe_coverage: Coverage
    """Coverage of the executions without an unsafe step (:func:`safe_executions`)."""
    random: bool = False
    """Uniformly random actions rather than the run's policy (the floor)."""

    def summary(self) -> dict[str, Any]:
        r, run = self.rollouts, self.run
        safe = safe_executions(r)
        out: dict[str, Any] = {
            "name": "random actions" if self.random else run.name,
            "mode": "random" if self.random else run.mode,
            "updates": 0 if self.random else run.updates,
            "executions": len(r.skills),
            "safe_executions": int(safe.sum()),
            "covered_cells": self.coverage.covered,
            "safe_covered_cells": self.safe_coverage.covered,
            "total_cells": self.coverage.total,
            "coverage_fraction": self.coverage.covered / self.coverage.total,
            "safe_coverage_fraction": self.safe_coverage.covered / self.coverage.total,
            "per_grid": self.coverage.per_grid(),
            "outside_points": int(sum(self.coverage.outside)),
            "return_mean": float(np.mean(r.returns)),
            "violation_rate_mean": float(np.mean(r.violation_rate)),
            "nonfinite_actions": r.nonfinite_actions,
        }
        rep = run.repertoire
        if not self.random and r.achieved is not None and rep is not None and len(rep) > 1:
            dist = skill_distance(r.achieved, r.skills, rep.cov)
            delta = rep.delta()
            out.update(
                delta=delta,
                distance_median=float(np.median(dist)),
                within_delta_fraction=float(np.mean(dist <= delta)),
            )
        return out


def safe_executions(r: Rollouts) -> np.ndarray:
    """Which executions had no unsafe step (K,) bool."""
    return np.asarray(r.violation_rate) <= 0.0


def execute_for_coverage(
    run: LoadedRun,
    label: str,
    n_skills: int,
    steps: int,
    bins: int,
    settle: int | None = None,
    executions: int | None = None,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
    random: bool = False,
) -> DiversityRun:
    """Execute a run's skills (or, without skills or with ``random`` actions, ``executions``
    repetitions of its policy) and bin the mean features. ``n_skills <= 0``: every skill of
    the repertoire."""
    cfg = run.config
    policy = None if random else run.require_policy()
    key, specs = coverage_specs(cfg, bins)
    skilled = run.uses_skills and not random
    if skilled:
        skills, ids = distinct_skills(run, n_skills)
    else:
        k = executions if executions is not None else max(n_skills, 1)
        skills, ids = np.zeros((k, 0)), np.arange(k)
    env = run.env(seed=seed)
    try:
        rollouts = execute_skills(
            policy,
            env,
            skills,
            steps,
            record=(key,),
            phi_key=cfg.feature_input_key if skilled else None,
            settle=settle,
            explore=explore,
            seed=seed,
            progress=progress,
            desc=f"diversity {label}",
        )
    finally:
        env.close()
    means = rollouts.means[key]
    safe = coverage(means[safe_executions(rollouts)], specs)
    return DiversityRun(label, run, rollouts, key, coverage(means, specs), ids, safe, random)


def run_diversity(
    run: LoadedRun,
    baseline: LoadedRun | None = None,
    n_skills: int | None = None,
    steps: int | None = None,
    bins: int = 20,
    settle: int | None = None,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
    random: bool = True,
) -> list[DiversityRun]:
    """Coverage of ``run`` (and of ``baseline`` and of uniformly ``random`` actions, each
    executed as many times). Defaults: N_z skills, T = the run's skill period."""
    n = run.config.repertoire.n_z if n_skills is None else n_skills
    t = run.config.collector.skill_period if steps is None else steps
    main = execute_for_coverage(run, "ursa", n, t, bins, settle, None, seed, explore, progress)
    out = [main]
    if baseline is not None:
        if baseline.config.env != run.config.env:
            raise ValueError("the baseline must run on the same env")
        out.append(
            execute_for_coverage(
                baseline,
                "baseline",
                n,
                t,
                bins,
                settle,
                len(main.rollouts.skills),
                seed,
                explore,
                progress,
            )
        )
    if random:
        k = len(main.rollouts.skills)
        out.append(
            execute_for_coverage(
                run, "random", n, t, bins, settle, k, seed, explore, progress, random=True
            )
        )
    return out


def write_diversity(results: list[DiversityRun], out: Path, bins: int) -> dict[str, Any]:
    """diversity.json, diversity_means.csv and diversity.png; returns the JSON summary."""
    first = results[0]
    summary: dict[str, Any] = {
        "figure": "Figure 4: coverage of the mean joint angles (mean position on the point env)",
        "env": first.run.config.env,
        "feature_key": first.key,
        "bins": bins,
        "steps": first.rollouts.steps,
        "settle": first.rollouts.settle,
        "grids": [
            {"name": s.name, "dims": s.dims, "low": s.low, "high": s.high, "bins": s.bins}
            for s in first.coverage.specs
        ],
        "runs": {r.label: r.summary() for r in results},
    }
    by_label = {r.label: r for r in results}
    if "baseline" in by_label:
        base = by_label["baseline"].coverage.covered
        summary["ratio"] = first.coverage.covered / base if base else float("inf")
        safe_base = by_label["baseline"].safe_coverage.covered
        safe = first.safe_coverage.covered
        summary["safe_ratio"] = safe / safe_base if safe_base else float("inf") if safe else 0.0
    if "random" in by_label:
        floor = by_label["random"].safe_coverage.covered
        safe = first.safe_coverage.covered
        summary["safe_ratio_random"] = safe / floor if floor else float("inf") if safe else 0.0
    write_json(out / "diversity.json", summary)

    rows = []
    for r in results:
        m = r.rollouts.means[r.key]
        for i in range(len(m)):
            skill = r.rollouts.skills[i]
            rows.append(
                [
                    r.label,
                    r.run.name,
                    i,
                    int(r.skill_ids[i]),
                    " ".join(f"{v:.6g}" for v in skill),
                    *m[i].tolist(),
                    r.rollouts.returns[i],
                    r.rollouts.violation_rate[i],
                ]
            )
    dim = first.rollouts.means[first.key].shape[1]
    header = [
        "label",
        "run",
        "index",
        "skill_id",
        "skill",
        *[f"mean_{first.key}_{j}" for j in range(dim)],
        "return",
        "violation_rate",
    ]
    write_csv(out / "diversity_means.csv", header, rows)

    for r in results:
        cells = []
        for s, c in zip(r.coverage.specs, r.coverage.counts, strict=True):
            for idx in np.ndindex(c.shape):
                cells.append([r.label, s.name, " ".join(map(str, idx)), int(c[idx])])
        write_csv(out / f"diversity_cells_{r.label}.csv", ["label", "grid", "cell", "count"], cells)
    _plot(results, out / "diversity.png")
    return summary


def _mode(r: DiversityRun) -> str:
    return "random" if r.random else r.run.mode


def _plot(results: list[DiversityRun], path: Path) -> None:
    """Per run, the cells its safe executions cover."""
    plt = pyplot()
    env = results[0].run.config.env
    if env == "a1":
        fig, axes = plt.subplots(
            len(results),
            3,
            figsize=(13, 2.4 * len(results) + 0.8),
            squeeze=False,
            constrained_layout=True,
        )
        for row, r in enumerate(results):
            for j, part in enumerate(JOINT_TYPES):
                ax = axes[row][j]
                cov = r.safe_coverage
                specs = [s for s in cov.specs if s.name.endswith(part)]
                grid = np.stack([cov.counts[cov.specs.index(s)] for s in specs])
                lo, hi = specs[0].low[0], specs[0].high[0]
                shown = np.where(grid > 0, np.log1p(grid), np.nan)
                ax.imshow(
                    shown,
                    aspect="auto",
                    cmap="viridis",
                    origin="upper",
                    extent=(lo, hi, len(LEGS) - 0.5, -0.5),
                    interpolation="nearest",
                )
                ax.set_facecolor("#f2f2f2")
                ax.set_yticks(range(len(LEGS)), LEGS)
                n_cov = int(np.count_nonzero(grid))
                ax.set_title(
                    f"{r.label} ({_mode(r)}): {part}, {n_cov}/{grid.size} safe cells", fontsize=9
                )
                if row == len(results) - 1:
                    ax.set_xlabel("mean joint angle (rad)")
    else:
        fig, axes = plt.subplots(
            1,
            len(results),
            figsize=(4.2 * len(results), 4.2),
            squeeze=False,
            constrained_layout=True,
        )
        for j, r in enumerate(results):
            ax = axes[0][j]
            spec, grid = r.safe_coverage.specs[0], r.safe_coverage.counts[0]
            shown = np.where(grid > 0, np.log1p(grid), np.nan).T
            ax.imshow(
                shown,
                origin="lower",
                cmap="viridis",
                interpolation="nearest",
                extent=(spec.low[0], spec.high[0], spec.low[1], spec.high[1]),
            )
            ax.set_facecolor("#f2f2f2")
            ax.set_title(
                f"{r.label} ({_mode(r)}): {r.safe_coverage.covered}/{r.coverage.total} safe cells",
                fontsize=9,
            )
            ax.set_xlabel("mean x")
            ax.set_ylabel("mean y")
    fig.suptitle(
        "Coverage of the skills' mean features (colour: log(1 + skills per cell))", fontsize=10
    )
    save_figure(fig, path)
