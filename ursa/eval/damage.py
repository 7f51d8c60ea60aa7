"""``ursa eval damage``: returns on a damaged robot (paper Figure 5), under one protocol for
every method.

For each frozen-joint scenario of ``DAMAGE_SCENARIOS`` (the hip, upper or lower joint of the
front-right or rear-right leg held at its standing angle):

1. **Selection**: K trials of T steps on the damaged robot. URSA tries its K most distinct
   skills; a policy without skills (``daydreamer``) is executed K times (it has one behaviour,
   so its trials differ only by the action noise).
2. **The same selection rule** for both: the candidate of the highest selection return (URSA:
   that skill; the baseline: its one policy).
3. **Score**: the mean return of ``fresh`` new trials of the selected candidate (other action
   noise), never the selection trials themselves, whose maximum over K would flatter whoever
   has more candidates.

Every trial starts from the robot righted where it stands, with a fresh policy memory, and
without the env's rescue (which would right a fallen robot and hand it returns it did not
earn), so trials are independent and comparable. The runs compared must share the task and
reward settings of the A1 (checked). Over several runs per algorithm the figure shows the
median and the range (min to max).
"""

from __future__ import annotations

import dataclasses
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
    """Mean return of the fresh trials of the selected candidate."""
    returns: np.ndarray
    """Selection return of every skill / trial (K,)."""
    fresh_returns: np.ndarray
    """Returns of the fresh trials that give the score."""
    best_skill_id: int = -1
    best_skill: list[float] = field(default_factory=list)
    nonfinite_actions: int = 0


FRESH_SEED = 10_007
"""Added to the seed of the fresh trials, so that their action noise is not the selection's."""
EVAL_FIELDS = ("rescue", "rescue_after", "rescue_on", "frozen_joints", "damage", "init_yaw")
"""A1 settings an evaluation sets itself; every other one (task, reward, control) must be the
same in the runs compared."""


def check_same_task(runs: list[LoadedRun]) -> None:
    """Raise ValueError unless every run's A1 has the same task, reward and control settings."""
    if not runs:
        return

    def key(run: LoadedRun) -> dict[str, Any]:
        a1 = run.config.a1
        return {
            f.name: getattr(a1, f.name) for f in dataclasses.fields(a1) if f.name not in EVAL_FIELDS
        }

    ref = key(runs[0])
    for run in runs[1:]:
        other = key(run)
        diff = sorted(k for k in ref if ref[k] != other[k])
        if diff:
            raise ValueError(
                f"{run.name} and {runs[0].name} differ in the A1's "
                + ", ".join(f"{k} ({other[k]!r} vs {ref[k]!r})" for k in diff)
                + ": their returns are not comparable"
            )


def evaluate_damage(
    run: LoadedRun,
    label: str,
    scenarios: list[str],
    n_skills: int,
    steps: int,
    fresh: int = 3,
    rescue: bool = False,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> list[DamageTrial]:
    """The score of ``run`` on each scenario (``intact``: no damage): K = ``n_skills``
    selection trials, the best candidate, the mean return of ``fresh`` new trials of it."""
    if run.config.env != "a1":
        raise ValueError("the damage evaluation needs an A1 run")
    if fresh < 1:
        raise ValueError("need at least one fresh trial")
    policy = run.require_policy()
    if run.uses_skills:
        skills, ids = distinct_skills(run, n_skills)
    else:
        skills, ids = np.zeros((max(n_skills, 1), 0)), np.arange(max(n_skills, 1))
    out = []
    for sc in scenarios:
        damage = "" if sc == INTACT else sc
        desc = f"{run.name} {sc}"
        env = run.env(seed=seed, damage=damage, rescue=rescue)
        r = trials_on(env, policy, skills, steps, explore, seed, progress, desc)
        best = int(np.argmax(r.returns))
        again = np.repeat(skills[best : best + 1], fresh, axis=0)
        env = run.env(seed=seed + FRESH_SEED, damage=damage, rescue=rescue)
        f = trials_on(env, policy, again, steps, explore, seed + FRESH_SEED, progress, desc)
        out.append(
            DamageTrial(
                label,
                run.name,
                run.mode,
                sc,
                float(np.mean(f.returns)),
                r.returns,
                f.returns,
                int(ids[best]) if run.uses_skills else -1,
                skills[best].tolist() if run.uses_skills else [],
                r.nonfinite_actions + f.nonfinite_actions,
            )
        )
    return out


def run_damage(
    runs: list[LoadedRun],
    baselines: list[LoadedRun],
    scenarios: list[str] | None = None,
    n_skills: int | None = None,
    steps: int | None = None,
    fresh: int = 3,
    rescue: bool = False,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> list[DamageTrial]:
    """Every run (label ``ursa``) and baseline (label ``baseline``) on every scenario, each
    with the same K selection trials (default: the first run's N_z), T steps (default: the
    first run's skill period) and ``fresh`` scoring trials."""
    scenarios = scenarios if scenarios else list(DAMAGE_SCENARIOS)
    bad = [s for s in scenarios if s != INTACT and s not in DAMAGE_SCENARIOS]
    if bad:
        raise ValueError(f"unknown scenarios {bad}; choose from {[*DAMAGE_SCENARIOS, INTACT]}")
    every = [*runs, *baselines]
    if not every:
        return []
    check_same_task(every)
    first = every[0].config
    n = first.repertoire.n_z if n_skills is None else n_skills
    t = first.collector.skill_period if steps is None else steps
    trials_out: list[DamageTrial] = []
    for label, group in (("ursa", runs), ("baseline", baselines)):
        for run in group:
            trials_out += evaluate_damage(
                run, label, scenarios, n, t, fresh, rescue, seed, explore, progress
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
        "figure": "Figure 5: return on the damaged robot (each method: K selection trials, the "
        "best candidate, scored by the mean of fresh trials of it), median and range over runs",
        "steps": steps,
        "skills_tried": n_skills,
        "fresh_trials": len(trials[0].fresh_returns) if trials else 0,
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
                "fresh_returns": t.fresh_returns,
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
