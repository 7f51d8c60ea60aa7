"""``ursa eval adapt``: damage adaptation with Intelligent Trial and Error (docs/adapt.md).

For each damage scenario (the six of ``DAMAGE_SCENARIOS`` by default, or any set of frozen
joints), return against trial number for:

- **ITE** (:mod:`ursa.adapt`) over the run's N_z most distinct skills, whose map is their
  intact return (measured once per run and policy, cached in ``<run>/eval/adapt/``);
- **random search** over the same skills with the same budget;
- **DayDreamer** (``--baseline``): its policy without adaptation, one execution per seed.

Every trial is one execution of a skill for T steps on the damaged robot, righted where it
stands with a fresh policy memory and without the env's rescue, as in ``ursa eval damage``.
Seeds change the env, the action noise and random search's order; the figure shows the median
and the range over seeds of the best return so far. Unless ``--no-reference``, every skill is
also executed once on each damaged robot, which gives the best skill's damaged return and the
number of trials each method needs to reach 90 % of it. The command line is
:class:`ursa.eval.cli.AdaptArgs`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ursa import adapt, scoring
from ursa.adapt import AdaptResult, ITEParams, SkillMap
from ursa.envs.a1 import DAMAGE_SCENARIOS, JOINT_NAMES
from ursa.eval.common import distinct_skills, pyplot, save_figure, write_csv, write_json
from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import execute_skills, trials_on
from ursa.rundir import RunDir

INTACT = "intact"
REACH = 0.9
"""Fraction of the best skill's damaged return the trials-to-reach numbers count up to."""


@dataclass(frozen=True)
class Scenario:
    """A damage: a label and the frozen joints (indices into ``JOINT_NAMES``)."""

    label: str
    frozen: tuple[int, ...]


def parse_scenario(spec: str) -> Scenario:
    """A preset (``front_upper``), ``intact``, or frozen joints separated by ``+`` or ``,``:
    indices 0..11 or names of ``JOINT_NAMES`` (``FL_lower`` or ``FL_lower_joint``)."""
    if spec in DAMAGE_SCENARIOS:
        return Scenario(spec, tuple(DAMAGE_SCENARIOS[spec]))
    if spec == INTACT:
        return Scenario(INTACT, ())
    short = {n.removesuffix("_joint"): i for i, n in enumerate(JOINT_NAMES)}
    joints: list[int] = []
    for part in spec.replace(",", "+").split("+"):
        p = part.strip()
        if p.isdigit() and 0 <= int(p) < len(JOINT_NAMES):
            joints.append(int(p))
        elif p.removesuffix("_joint") in short:
            joints.append(short[p.removesuffix("_joint")])
        else:
            raise ValueError(
                f"unknown damage {spec!r}: use {sorted(DAMAGE_SCENARIOS)}, {INTACT!r}, or "
                f"joints (0..11 or {', '.join(short)}) joined by '+'"
            )
    frozen = tuple(sorted(set(joints)))
    return Scenario("+".join(JOINT_NAMES[j].removesuffix("_joint") for j in frozen), frozen)


def _checkpoint_digest(run: LoadedRun) -> str:
    if run.run_dir is not None and RunDir(run.run_dir).checkpoint.is_file():
        return hashlib.sha256(RunDir(run.run_dir).checkpoint.read_bytes()).hexdigest()[:16]
    return f"updates-{run.updates}"


def intact_map(
    run: LoadedRun,
    n_skills: int,
    steps: int,
    seed: int = 0,
    explore: bool = scoring.EXPLORE,
    rescue: bool = False,
    progress: bool = True,
) -> tuple[SkillMap, dict[str, Any]]:
    """ITE's map: the intact return of the run's ``n_skills`` most distinct skills, each
    executed once for ``steps`` steps from a righted robot. Read from the run directory's cache
    when the same checkpoint, skills, T, seed and action mode were measured before; otherwise
    measured and written there. Returns the map and ``{"cached", "path", "key"}``."""
    policy = run.require_policy()
    skills, ids = distinct_skills(run, n_skills)
    key = adapt.map_key(
        kind="eval-intact",
        checkpoint=_checkpoint_digest(run),
        skills=np.asarray(skills, np.float64),
        ids=np.asarray(ids, np.int64),
        steps=steps,
        seed=seed,
        explore=explore,
        rescue=rescue,
        env=run.config.env,
    )
    path = adapt.map_path(run.run_dir, key) if run.run_dir is not None else None
    if path is not None:
        got = adapt.load_map(path)
        if got is not None:
            return got[0], {"cached": True, "path": path, "key": key}
    env = run.env(seed=seed, damage="", rescue=rescue)
    r = trials_on(env, policy, skills, steps, explore, seed, progress, f"{run.name} intact map")
    m = SkillMap(skills, r.returns, ids)
    if path is not None:
        adapt.save_map(
            path, m, {"steps": steps, "seed": seed, "explore": explore, "updates": run.updates}
        )
    return m, {"cached": False, "path": path, "key": key}


class _Trials:
    """Executions of map rows on one damaged env (each from a righted robot, fresh memory)."""

    def __init__(
        self, run: LoadedRun, env: Any, m: SkillMap, steps: int, seed: int, explore: bool
    ) -> None:
        self.run, self.env, self.m = run, env, m
        self.steps, self.seed, self.explore = steps, seed, explore
        self.count = 0
        self.nonfinite = 0

    def __call__(self, row: int) -> float:
        skills = self.m.skills[row : row + 1] if self.run.uses_skills else np.zeros((1, 0))
        r = execute_skills(
            self.run.require_policy(),
            self.env,
            skills,
            self.steps,
            restand=True,
            explore=self.explore,
            seed=self.seed * 100_003 + self.count,
            progress=False,
        )
        self.count += 1
        self.nonfinite += r.nonfinite_actions
        return float(r.returns[0])


def _env(run: LoadedRun, sc: Scenario, seed: int, rescue: bool) -> Any:
    if sc.frozen and run.config.env != "a1":
        raise ValueError(f"frozen joints need an A1 run; this one is {run.config.env!r}")
    if run.config.env == "a1":
        return run.env(seed=seed, damage="", rescue=rescue, frozen_joints=sc.frozen)
    return run.env(seed=seed)


def _stats(values: list[float]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], np.float64)
    if not len(v):
        return {"median": None, "min": None, "max": None, "n": 0.0}
    return {
        "median": float(np.median(v)),
        "min": float(v.min()),
        "max": float(v.max()),
        "n": float(len(v)),
    }


def _curve_stats(curves: list[np.ndarray]) -> dict[str, list[float]]:
    c = np.stack(curves)
    return {
        "median": np.median(c, 0).tolist(),
        "min": c.min(0).tolist(),
        "max": c.max(0).tolist(),
    }


def _method_summary(
    m: SkillMap,
    results: list[AdaptResult],
    seeds: list[int],
    budget: int,
    target: float | None,
) -> dict[str, Any]:
    runs: list[dict[str, Any]] = []
    curves = []
    for s, r in zip(seeds, results, strict=True):
        curves.append(adapt.best_so_far(r.returns, budget))
        reach = None if target is None else adapt.trials_to_reach(r.returns, target)
        runs.append(
            {
                "seed": s,
                "stop_reason": r.reason,
                "n_trials": len(r.trials),
                "chosen_skill_id": r.chosen.skill_id,
                "chosen_return": r.chosen.ret,
                "trials_to_reach": reach,
                "trials": [
                    {
                        "row": t.index,
                        "skill_id": t.skill_id,
                        "return": t.ret,
                        "predicted": t.predicted,
                        "predicted_best_id": (
                            int(m.ids[t.predicted_best]) if t.predicted_best >= 0 else None
                        ),
                        "predicted_best_mean": t.predicted_best_mean,
                    }
                    for t in r.trials
                ],
            }
        )
    out: dict[str, Any] = {
        "best_so_far": _curve_stats(curves),
        "trials": _stats([float(len(r.trials)) for r in results]),
        "chosen_return": _stats([r.chosen.ret for r in results]),
        "runs": runs,
    }
    if target is not None:
        # a method that never reached the target within the budget counts as budget + 1
        counts = [float(run["trials_to_reach"] or budget + 1) for run in runs]
        out["trials_to_reach"] = _stats(counts)
        out["reached"] = sum(run["trials_to_reach"] is not None for run in runs)
    return out


def run_adapt(
    run: LoadedRun,
    baselines: list[LoadedRun],
    scenarios: list[str] | None = None,
    n_skills: int | None = None,
    steps: int | None = None,
    params: ITEParams | None = None,
    seeds: int = 5,
    seed: int = 0,
    reference: bool = True,
    rescue: bool = False,
    explore: bool = scoring.EXPLORE,
    progress: bool = True,
) -> dict[str, Any]:
    """Everything ``adapt.json`` holds (see the module docstring)."""
    if not run.uses_skills:
        raise ValueError("adaptation picks skills: the run must use skills (not daydreamer)")
    params = params or ITEParams()
    n = run.config.repertoire.n_z if n_skills is None else n_skills
    t = run.config.collector.skill_period if steps is None else steps
    if scenarios is None:
        scenarios = list(DAMAGE_SCENARIOS) if run.config.env == "a1" else [INTACT]
    parsed = [parse_scenario(s) for s in scenarios]
    m, cache = intact_map(run, n, t, seed, explore, rescue, progress)
    seed_list = [seed + k for k in range(seeds)]
    out: dict[str, Any] = {
        "figure": "Damage adaptation: best return so far against trials on the damaged robot "
        "(ITE and random search over the repertoire; DayDreamer without adaptation), median "
        "and range over seeds",
        "run": run.name,
        "mode": run.mode,
        "steps": t,
        "skills": len(m),
        "seeds": seed_list,
        "params": dataclasses.asdict(params),
        "reach_fraction": REACH,
        "map": {
            "cached": cache["cached"],
            "path": cache["path"],
            "key": cache["key"],
            "skill_ids": m.ids,
            "returns": m.prior,
            "best_skill_id": int(m.ids[int(np.argmax(m.prior))]),
            "best_return": float(m.prior.max()),
        },
        "scenarios": {},
        "nonfinite_actions": 0,
    }
    nonfinite = 0
    for sc in parsed:
        entry: dict[str, Any] = {
            "frozen_joints": list(sc.frozen),
            "frozen_joint_names": [JOINT_NAMES[j] for j in sc.frozen],
        }
        target = None
        if reference:
            r = trials_on(
                _env(run, sc, seed, rescue),
                run.require_policy(),
                m.skills,
                t,
                explore,
                seed,
                progress,
                f"{run.name} {sc.label} reference",
            )
            nonfinite += r.nonfinite_actions
            best = int(np.argmax(r.returns))
            ref = float(r.returns[best])
            target = params.floor + REACH * (ref - params.floor)
            entry["reference"] = {
                "best_skill_id": int(m.ids[best]),
                "best_return": ref,
                "target": target,
                "returns": r.returns,
            }
        ite_res, rnd_res = [], []
        for s in seed_list:
            env = _env(run, sc, s, rescue)
            try:
                fn = _Trials(run, env, m, t, s, explore)
                ite_res.append(adapt.ite(m, fn, params))
                fr = _Trials(run, env, m, t, s + 7919, explore)
                rnd_res.append(adapt.random_search(m, fr, params.budget, s))
                nonfinite += fn.nonfinite + fr.nonfinite
            finally:
                env.close()
        entry["ite"] = _method_summary(m, ite_res, seed_list, params.budget, target)
        entry["random"] = _method_summary(m, rnd_res, seed_list, params.budget, target)
        dd: dict[str, Any] = {}
        for b in baselines:
            rets = []
            for s in seed_list:
                env = _env(b, sc, s, rescue)
                try:
                    fb = _Trials(b, env, m, t, s, explore)
                    rets.append(fb(0))
                    nonfinite += fb.nonfinite
                finally:
                    env.close()
            dd[b.name] = rets
        if dd:
            allr = [x for v in dd.values() for x in v]
            entry["daydreamer"] = {"runs": dd, **_stats(allr)}
        out["scenarios"][sc.label] = entry
    out["nonfinite_actions"] = nonfinite
    out["summary"] = _summary(out)
    return out


def _summary(out: dict[str, Any]) -> dict[str, Any]:
    """Medians over scenarios of the per-scenario medians."""
    scs = list(out["scenarios"].values())

    def med(method: str, key: str) -> float | None:
        v = [e[method][key]["median"] for e in scs if key in e[method]]
        v = [x for x in v if x is not None]
        return float(np.median(v)) if v else None

    s: dict[str, Any] = {
        "ite_trials_median": med("ite", "trials"),
        "ite_chosen_return_median": med("ite", "chosen_return"),
        "random_chosen_return_median": med("random", "chosen_return"),
    }
    if scs and "reference" in scs[0]:
        s["ite_trials_to_reach_median"] = med("ite", "trials_to_reach")
        s["random_trials_to_reach_median"] = med("random", "trials_to_reach")
    return s


def write_adapt(res: dict[str, Any], out: Path) -> dict[str, Any]:
    """adapt.json, adapt.csv and adapt.png; returns the JSON's content."""
    write_json(out / "adapt.json", res)
    rows = []
    for label, e in res["scenarios"].items():
        for method in ("ite", "random"):
            for r in e[method]["runs"]:
                best = -np.inf
                for k, t in enumerate(r["trials"], 1):
                    best = max(best, t["return"])
                    rows.append([method, label, r["seed"], k, t["skill_id"], t["return"], best])
        for name, rets in e.get("daydreamer", {}).get("runs", {}).items():
            for s, ret in zip(res["seeds"], rets, strict=True):
                rows.append([f"daydreamer:{name}", label, s, 1, -1, ret, ret])
    write_csv(
        out / "adapt.csv",
        ["method", "scenario", "seed", "trial", "skill_id", "return", "best_so_far"],
        rows,
    )
    _plot(res, out / "adapt.png")
    return res


def _plot(res: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    labels = list(res["scenarios"])
    ncol = min(3, len(labels))
    nrow = (len(labels) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False)
    budget = int(res["params"]["budget"])
    x = np.arange(1, budget + 1)
    for ax, label in zip(axes.ravel(), labels, strict=False):
        e = res["scenarios"][label]
        for method, color in (("ite", "tab:blue"), ("random", "tab:grey")):
            c = e[method]["best_so_far"]
            med = np.asarray(c["median"], np.float64)
            ax.plot(x, med, color=color, lw=1.8, label="ITE" if method == "ite" else "random")
            ax.fill_between(x, c["min"], c["max"], color=color, alpha=0.2, lw=0)
        stops = [r["n_trials"] for r in e["ite"]["runs"]]
        ax.axvline(float(np.median(stops)), color="tab:blue", ls=":", lw=1, label="ITE stops")
        if "daydreamer" in e and e["daydreamer"]["median"] is not None:
            d = e["daydreamer"]
            ax.axhline(d["median"], color="tab:orange", lw=1.5, label="DayDreamer")
            ax.axhspan(d["min"], d["max"], color="tab:orange", alpha=0.15, lw=0)
        if "reference" in e:
            ax.axhline(e["reference"]["best_return"], color="k", ls="--", lw=1, label="best skill")
            ax.axhline(e["reference"]["target"], color="k", ls=":", lw=0.8, label="90 %")
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("trial")
        ax.set_ylabel("best return so far")
    for ax in axes.ravel()[len(labels) :]:
        ax.set_axis_off()
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle("Adaptation to damage: median and range over seeds", fontsize=11)
    fig.tight_layout()
    save_figure(fig, path)
