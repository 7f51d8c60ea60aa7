"""``ursa eval velocity``: tracking error over the reachable skill space (paper Figure 6).

For a run with a provided 2-D feature function (``--core.feature velocity`` on the A1, mode
``ursa-supervised``: φ = (forward velocity, yaw rate)), a grid of targets covers what the
run's skills reach: by default the policy first executes the N_z most distinct skills of the
repertoire for T steps each, and the grid spans the q to 1 − q quantiles (q = 0.1) of their
**mean** features. The repertoire itself holds per-step features, whose extremes (a stumble, a
spin) no skill holds on average for T steps, so a grid over their bounding box (``grid_from
repertoire``, ``quantile`` 0) asks for targets no skill can track. The policy then executes
each target as its skill for T steps (targets visited in a serpentine order so that neighbours
follow each other, without resets), and the tracking error of each dimension is
|mean φ over the steps − target| (the skill's definition: the expected feature). The per-step
error, mean over the steps of |φ_t − target|, is reported too. On the A1 the figure is the
paper's §5.3 experiment, the posture task: a run of another task is refused unless
``any_task``. Any provided 2-D feature works the same way (the point env's position: position
tracking).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ursa import scoring
from ursa.eval.common import (
    distinct_skills,
    feature_names,
    pyplot,
    save_figure,
    write_csv,
    write_json,
)
from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import Rollouts, execute_skills


@dataclass
class VelocityResult:
    run: LoadedRun
    axes: list[np.ndarray]
    """Target values along each dimension (G,) each."""
    targets: np.ndarray
    """(G, G, 2) grid of targets; [i, j] = (axes[0][i], axes[1][j])."""
    achieved: np.ndarray
    """(G, G, 2) mean φ."""
    error: np.ndarray
    """(G, G, 2) |achieved − target|."""
    step_error: np.ndarray
    """(G, G, 2) mean of |φ_t − target|."""
    rollouts: Rollouts
    names: list[str]
    margin: float
    quantile: float = 0.0
    grid_from: str = "achieved"
    grid_points: np.ndarray | None = None
    """(K, 2) the points the grid spans: the skills' mean features (``achieved``) or the
    repertoire's entries (``repertoire``)."""


QUANTILE = 0.1
"""Default q of the target grid: it spans the q to 1 − q quantiles of its points."""


def target_grid(
    skills: np.ndarray, n: int, margin: float = 0.0, quantile: float = 0.0
) -> list[np.ndarray]:
    """``n`` evenly spaced targets per dimension over the bounding box of ``skills`` (N, D)
    (with ``quantile`` q > 0: from the q to the 1 − q quantile of each dimension, so that a few
    outliers do not stretch it), widened by ``margin`` × its width on each side."""
    pts = np.asarray(skills, np.float64)
    lo, hi = np.quantile(pts, quantile, axis=0), np.quantile(pts, 1.0 - quantile, axis=0)
    flat = hi - lo <= 1e-9  # a degenerate box still gets a grid of distinct targets
    lo, hi = np.where(flat, lo - 1e-3, lo), np.where(flat, hi + 1e-3, hi)
    pad = margin * (hi - lo)
    return [np.linspace(a - p, b + p, n) for a, b, p in zip(lo, hi, pad, strict=True)]


def serpentine(n0: int, n1: int) -> list[tuple[int, int]]:
    """Grid indices row by row, every other row reversed (consecutive targets are neighbours)."""
    return [(i, j if i % 2 == 0 else n1 - 1 - j) for i in range(n0) for j in range(n1)]


def run_velocity(
    run: LoadedRun,
    grid: int = 7,
    steps: int | None = None,
    settle: int | None = None,
    margin: float = 0.0,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
    quantile: float = QUANTILE,
    grid_from: Literal["achieved", "repertoire"] = "achieved",
    n_skills: int | None = None,
    any_task: bool = False,
) -> VelocityResult:
    cfg = run.config
    if cfg.learned_feature or not run.uses_skills or cfg.skill_dim != 2:
        raise ValueError(
            "the velocity evaluation needs a run with a provided 2-D feature function "
            f"(--core.feature velocity, mode ursa-supervised); this run has feature "
            f"{cfg.feature!r}, mode {cfg.learner.mode!r}"
        )
    if cfg.env == "a1" and cfg.a1.task != "posture" and not any_task:
        raise ValueError(
            f"Figure 6 is the posture task's experiment (§5.3); this run trained the "
            f"{cfg.a1.task!r} task (--any-task measures it anyway)"
        )
    policy = run.require_policy()
    rep = run.require_repertoire()
    t = cfg.collector.skill_period if steps is None else steps

    def execute(skills: np.ndarray, desc: str) -> Rollouts:
        env = run.env(seed=seed)
        try:
            return execute_skills(
                policy,
                env,
                skills,
                t,
                record=(cfg.feature,),
                phi_key=cfg.feature,
                tracking=True,
                settle=settle,
                explore=explore,
                seed=seed,
                progress=progress,
                desc=desc,
            )
        finally:
            env.close()

    if grid_from == "achieved":
        n = cfg.repertoire.n_z if n_skills is None else n_skills
        probe = execute(distinct_skills(run, n)[0], "skills for the grid")
        points = np.asarray(probe.means[cfg.feature], np.float64)
    elif grid_from == "repertoire":
        points = np.asarray(rep.skills, np.float64)
    else:
        raise ValueError(f"grid_from must be achieved or repertoire, not {grid_from!r}")
    axes = target_grid(points, grid, margin, quantile)
    order = serpentine(grid, grid)
    targets = np.array([[axes[0][i], axes[1][j]] for i, j in order])
    r = execute(targets, "velocity targets")
    shape = (grid, grid, 2)
    tg, ach, err, serr = (np.zeros(shape) for _ in range(4))
    mean = r.means[cfg.feature]
    for k, (i, j) in enumerate(order):
        tg[i, j] = targets[k]
        ach[i, j] = mean[k]
        err[i, j] = np.abs(mean[k] - targets[k])
        serr[i, j] = r.abs_error[cfg.feature][k]
    return VelocityResult(
        run,
        axes,
        tg,
        ach,
        err,
        serr,
        r,
        feature_names(cfg.feature, 2),
        margin,
        quantile,
        grid_from,
        points,
    )


def write_velocity(res: VelocityResult, out: Path) -> dict[str, Any]:
    """velocity.json, velocity.csv and velocity.png; returns the JSON summary."""
    names = res.names
    summary: dict[str, Any] = {
        "figure": "Figure 6: tracking error of each feature dimension over a grid of targets "
        "spanning the quantiles of the skills' mean features",
        "run": res.run.name,
        "feature": res.run.config.feature,
        "task": res.run.config.a1.task if res.run.config.env == "a1" else None,
        "grid_from": res.grid_from,
        "grid_points": res.grid_points,
        "dims": names,
        "grid": len(res.axes[0]),
        "steps": res.rollouts.steps,
        "settle": res.rollouts.settle,
        "margin": res.margin,
        "quantile": res.quantile,
        "axes": res.axes,
        "error_mean": res.error.reshape(-1, 2).mean(0),
        "error_median": np.median(res.error.reshape(-1, 2), axis=0),
        "error_max": res.error.reshape(-1, 2).max(0),
        "step_error_mean": res.step_error.reshape(-1, 2).mean(0),
        "violation_rate_mean": float(np.mean(res.rollouts.violation_rate)),
        "nonfinite_actions": res.rollouts.nonfinite_actions,
        "error": res.error,
    }
    write_json(out / "velocity.json", summary)
    rows = []
    g = len(res.axes[0])
    for i in range(g):
        for j in range(g):
            rows.append(
                [*res.targets[i, j], *res.achieved[i, j], *res.error[i, j], *res.step_error[i, j]]
            )
    write_csv(
        out / "velocity.csv",
        [
            "target_0",
            "target_1",
            "achieved_0",
            "achieved_1",
            "error_0",
            "error_1",
            "step_error_0",
            "step_error_1",
        ],
        rows,
    )
    _plot(res, out / "velocity.png")
    return summary


def _plot(res: VelocityResult, path: Path) -> None:
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.2))
    a0, a1 = res.axes
    d0 = (a0[1] - a0[0]) / 2 if len(a0) > 1 else 0.5
    d1 = (a1[1] - a1[0]) / 2 if len(a1) > 1 else 0.5
    extent = (a0[0] - d0, a0[-1] + d0, a1[0] - d1, a1[-1] + d1)
    skills = res.run.require_repertoire().skills
    for k, ax in enumerate(axs):
        im = ax.imshow(
            res.error[:, :, k].T,
            origin="lower",
            extent=extent,
            aspect="auto",
            cmap="magma_r",
            interpolation="nearest",
            vmin=0.0,
        )
        ax.scatter(skills[:, 0], skills[:, 1], s=2, c="cyan", alpha=0.3, label="repertoire")
        ax.set_xlabel(f"target {res.names[0]}")
        ax.set_ylabel(f"target {res.names[1]}")
        ax.set_title(
            f"|error| of {res.names[k]} (mean {res.error[:, :, k].mean():.3g})", fontsize=9
        )
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        fig.colorbar(im, ax=ax)
    axs[0].legend(fontsize=7, loc="upper right")
    fig.suptitle("Tracking error over the reachable space (lower is better)", fontsize=10)
    save_figure(fig, path)
