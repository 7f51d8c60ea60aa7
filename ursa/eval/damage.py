"""``ursa eval damage``: returns on a damaged robot (paper Figure 5).

For each frozen-joint scenario of ``DAMAGE_SCENARIOS`` (the hip, upper or lower joint of the
front-right or rear-right leg held at its standing angle), each of the N_z most distinct skills
of an URSA run is tried for T steps on the damaged robot and the best return is kept (adaptation
by choosing a skill from the repertoire). A run without skills (``daydreamer``) is executed
``trials`` times and its mean return kept. Every trial starts from the robot righted where it
stands, with a fresh policy memory, and without the env's rescue (which would right a fallen
robot and hand it returns it did not earn), so trials are independent and comparable. Over
several runs per algorithm the figure shows the median and the range (min to max).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ursa import scoring
from ursa.envs.a1 import DAMAGE_SCENARIOS
from ursa.eval.common import distinct_skills, pyplot, save_figure, write_csv, write_json
from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import trials_on

INTACT = "intact"


@dataclass
class DamageTrial:
    """One run on one scenario."""

    label: str
    run: str
    mode: str
    scenario: str
    score: float
    """Best skill's return (skills) or mean return over the trials (no skills)."""
    returns: np.ndarray
    """Return of every skill / trial."""
    best_skill_id: int = -1
    best_skill: list[float] = field(default_factory=list)
    nonfinite_actions: int = 0


def evaluate_damage(
    run: LoadedRun,
    label: str,
    scenarios: list[str],
    n_skills: int,
    steps: int,
    trials: int = 1,
    rescue: bool = False,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> list[DamageTrial]:
    """The score of ``run`` on each scenario (``intact``: no damage)."""
    if run.config.env != "a1":
        raise ValueError("the damage evaluation needs an A1 run")
    policy = run.require_policy()
    if run.uses_skills:
        skills, ids = distinct_skills(run, n_skills)
    else:
        skills, ids = np.zeros((trials, 0)), np.arange(trials)
    out = []
    for sc in scenarios:
        env = run.env(seed=seed, damage="" if sc == INTACT else sc, rescue=rescue)
        r = trials_on(env, policy, skills, steps, explore, seed, progress, f"{run.name} {sc}")
        if run.uses_skills:
            best = int(np.argmax(r.returns))
            out.append(
                DamageTrial(
                    label,
                    run.name,
                    run.mode,
                    sc,
                    float(r.returns[best]),
                    r.returns,
                    int(ids[best]),
                    skills[best].tolist(),
                    r.nonfinite_actions,
                )
            )
        else:
            out.append(
                DamageTrial(
                    label,
                    run.name,
                    run.mode,
                    sc,
                    float(np.mean(r.returns)),
                    r.returns,
                    nonfinite_actions=r.nonfinite_actions,
                )
            )
    return out


def run_damage(
    runs: list[LoadedRun],
    baselines: list[LoadedRun],
    scenarios: list[str] | None = None,
    n_skills: int | None = None,
    steps: int | None = None,
    trials: int = 1,
    rescue: bool = False,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> list[DamageTrial]:
    """Every run (label ``ursa``) and baseline (label ``baseline``) on every scenario."""
    scenarios = scenarios if scenarios else list(DAMAGE_SCENARIOS)
    bad = [s for s in scenarios if s != INTACT and s not in DAMAGE_SCENARIOS]
    if bad:
        raise ValueError(f"unknown scenarios {bad}; choose from {[*DAMAGE_SCENARIOS, INTACT]}")
    trials_out: list[DamageTrial] = []
    for label, group in (("ursa", runs), ("baseline", baselines)):
        for run in group:
            n = run.config.repertoire.n_z if n_skills is None else n_skills
            t = run.config.collector.skill_period if steps is None else steps
            trials_out += evaluate_damage(
                run, label, scenarios, n, t, trials, rescue, seed, explore, progress
            )
    return trials_out


def summarize(trials: list[DamageTrial]) -> dict[str, dict[str, dict[str, float]]]:
    """label -> scenario -> median, min, max and runs of the scores."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for label in dict.fromkeys(t.label for t in trials):
        out[label] = {}
        for sc in dict.fromkeys(t.scenario for t in trials):
            s = np.array([t.score for t in trials if t.label == label and t.scenario == sc])
            if len(s):
                out[label][sc] = {
                    "median": float(np.median(s)),
                    "min": float(s.min()),
                    "max": float(s.max()),
                    "runs": float(len(s)),
                }
    return out


def write_damage(
    trials: list[DamageTrial], out: Path, steps: int, n_skills: int, rescue: bool
) -> dict[str, Any]:
    """damage.json, damage.csv and damage.png; returns the JSON summary."""
    stats = summarize(trials)
    summary: dict[str, Any] = {
        "figure": "Figure 5: return on the damaged robot (URSA: best of its most distinct "
        "skills; baseline: its policy), median and range over runs",
        "steps": steps,
        "skills_tried": n_skills,
        "rescue": rescue,
        "scenarios": {
            s: list(DAMAGE_SCENARIOS.get(s, ())) for s in dict.fromkeys(t.scenario for t in trials)
        },
        "stats": stats,
        "runs": [
            {
                "label": t.label,
                "run": t.run,
                "mode": t.mode,
                "scenario": t.scenario,
                "score": t.score,
                "returns": t.returns,
                "best_skill_id": t.best_skill_id,
                "best_skill": t.best_skill,
                "nonfinite_actions": t.nonfinite_actions,
            }
            for t in trials
        ],
    }
    if "ursa" in stats and "baseline" in stats:
        summary["ursa_better"] = {
            sc: stats["ursa"][sc]["median"] > stats["baseline"][sc]["median"]
            for sc in stats["ursa"]
            if sc in stats["baseline"]
        }
    write_json(out / "damage.json", summary)
    write_csv(
        out / "damage.csv",
        ["label", "run", "mode", "scenario", "score", "best_skill_id", "n_trials"],
        [
            [t.label, t.run, t.mode, t.scenario, t.score, t.best_skill_id, len(t.returns)]
            for t in trials
        ],
    )
    _plot(trials, stats, out / "damage.png")
    return summary


def _plot(
    trials: list[DamageTrial], stats: dict[str, dict[str, dict[str, float]]], path: Path
) -> None:
    plt = pyplot()
    scenarios = list(dict.fromkeys(t.scenario for t in trials))
    labels = list(stats)
    fig, ax = plt.subplots(figsize=(1.4 * len(scenarios) + 2.5, 3.8))
    width = 0.8 / max(len(labels), 1)
    colors = {"ursa": "tab:blue", "baseline": "tab:orange"}
    x = np.arange(len(scenarios))
    for j, label in enumerate(labels):
        st = stats[label]
        med = np.array([st[s]["median"] if s in st else np.nan for s in scenarios])
        lo = np.array([st[s]["min"] if s in st else np.nan for s in scenarios])
        hi = np.array([st[s]["max"] if s in st else np.nan for s in scenarios])
        pos = x + (j - (len(labels) - 1) / 2) * width
        mode = next((t.mode for t in trials if t.label == label), label)
        ax.bar(pos, med, width * 0.9, color=colors.get(label), alpha=0.8, label=f"{label} ({mode})")
        ax.errorbar(pos, med, yerr=[med - lo, hi - med], fmt="none", ecolor="k", capsize=3)
        for i, sc in enumerate(scenarios):
            pts = [t.score for t in trials if t.label == label and t.scenario == sc]
            ax.scatter(np.full(len(pts), pos[i]), pts, s=8, color="k", zorder=3)
    ax.set_xticks(x, [s.replace("_", "\n") for s in scenarios])
    ax.set_ylabel("return over T steps")
    ax.axhline(0.0, color="grey", lw=0.5)
    ax.legend(fontsize=8)
    ax.set_title("Damage adaptation: median and range over runs", fontsize=10)
    save_figure(fig, path)
