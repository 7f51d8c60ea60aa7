"""Results and figure of the A1 posture-task runs with λ2's integrating floor (docs/learner.md,
"An integrating floor under λ2"): collects serial runs (``scripts/a1_serial.py --out``) and
their skill evaluations (``scripts/a1_skills.py --out``) into one JSON with the numbers the
docs quote, against the floor-less baseline of docs/results/a1_posture_long.json, and draws per
run the violation rate and λ2 (network mean and floor) against updates.

    .venv/bin/python scripts/a1_floor_figure.py --run NAME CURVE.json SKILLS.json [--run ...] \
        --baseline docs/results/a1_posture_long.json post_w1_s1 post_w1_s2 [--baseline ...] \
        --command "the a1_serial.py command of the runs" \
        --json docs/results/a1_posture_lambda2_floor.json --png docs/figures/a1_posture_floor.png

Each ``--baseline`` names an earlier results file (this script's or
docs/results/a1_posture_long.json) and the runs of it to draw in grey beside the new ones.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ursa.learner_config import LearnerConfig

DEFAULT_COMMAND = (
    "scripts/a1_serial.py --preset cpu --feature velocity --seed S --updates 9000 "
    "--minutes 44 --a1 task='\"posture\"' action_filter_hz=1.5 --collector "
    "random_scale=0.2 archive_window=1 --set lambda2_floor_lr=0.01 "
    "lambda2_floor_target=TARGET lambda2_floor_max=0.9 --out S.json --run-dir RUN; "
    "scripts/a1_skills.py RUN --skills 50 --out SKILLS.json"
)
"""The command of the first floor runs (docs/results/a1_posture_lambda2_floor.json)."""
LAST_S = 15 * 60
"""The issue's safety window: the last 15 minutes of a run."""


def _mean(xs: list[float]) -> float | None:
    return round(sum(xs) / len(xs), 4) if xs else None


def summarise(curve: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    """Violation windows of a curve (rows with updates and violation_rate, optionally t)."""
    rows = [r for r in curve if r["updates"] > 0]

    def between(a: int, b: int) -> float | None:
        return _mean([r["violation_rate"] for r in rows if a <= r["updates"] < b])

    if rows and "t" in rows[0]:
        end = rows[-1]["t"]
        last = [r["violation_rate"] for r in rows if r["t"] > end - LAST_S]
    else:  # evenly spaced rows over ``seconds``
        k = max(1, round(len(curve) * LAST_S / seconds))
        last = [r["violation_rate"] for r in curve[-k:]]
    return {
        "violation_2000_4000": between(2000, 4000),
        "violation_4000_6000": between(4000, 6000),
        "violation_from_6000": between(6000, 10**9),
        "violation_last_15_min": _mean(last),
    }


def floor_label(overrides: dict[str, Any] | None) -> str:
    """How a run's learner overrides set λ2's floor, for a legend ("no floor", "target 0.02,
    max 0.6"); a field not overridden has :class:`LearnerConfig`'s default."""
    o = overrides or {}
    if not o.get("lambda2_floor_lr"):
        return "no floor"
    target = o.get("lambda2_floor_target", LearnerConfig.lambda2_floor_target)
    return f"target {target}, max {o.get('lambda2_floor_max', LearnerConfig.lambda2_floor_max)}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--run", nargs=3, action="append", default=[], metavar=("NAME", "CURVE", "SKILLS")
    )
    ap.add_argument("--baseline", nargs="+", action="append", default=[], metavar="FILE_AND_RUNS")
    ap.add_argument("--machine", default="")
    ap.add_argument("--command", default=DEFAULT_COMMAND, help="the runs' command, recorded")
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--png", type=Path, required=True)
    a = ap.parse_args()

    runs: dict[str, Any] = {}
    for name, curve_path, skills_path in a.run:
        d = json.loads(Path(curve_path).read_text())
        ev = json.loads(Path(skills_path).read_text())
        runs[name] = {
            "seed": d["seed"],
            "learner_overrides": d["learner_overrides"],
            "a1_overrides": d["a1_overrides"],
            "collector_overrides": d["collector_overrides"],
            "updates": d["updates"],
            "seconds": round(d["seconds"], 1),
            **summarise(d["rows"], d["seconds"]),
            "skills_eval": {k: v for k, v in ev.items() if k != "run"},
            "curve": [
                {
                    k: r[k]
                    for k in (
                        "t",
                        "updates",
                        "violation_rate",
                        "lambda1",
                        "lambda2",
                        "lambda2_floor",
                        "within_delta",
                        "entropy",
                    )
                }
                for r in d["rows"]
            ],
        }
    # (file's index, index in its file, name, run) of every baseline run, each file read once
    base_runs: list[tuple[int, int, str, dict[str, Any]]] = []
    for i, (file, *names) in enumerate(a.baseline):
        src = json.loads(Path(file).read_text())["runs"]
        base_runs += [(i, j, n, {**src[n], "source": file}) for j, n in enumerate(names)]
    baseline: dict[str, Any] = {}
    for _, _, name, r in base_runs:
        ev = r["skills_eval"]
        baseline[name] = {
            "source": r["source"],
            "seed": r["seed"],
            "floor": floor_label(r.get("learner_overrides")),
            "updates": r["updates"],
            **summarise(r["curve"], r["seconds"]),
            "within_delta": ev["within_delta"],
            "eval_violation_rate": ev["violation_rate"],
        }
    out = {
        "machine": a.machine,
        "command": a.command,
        "baseline_source": sorted({file for file, *_ in a.baseline}) or None,
        "baseline": baseline,
        "runs": runs,
    }
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(13, 4.2))
    greys = ("0.45", "0.6", "0.75")
    for i, j, name, run in base_runs:
        c = [r for r in run["curve"] if r["updates"] > 0]
        up = [r["updates"] for r in c]
        label = f"{name}: seed {run['seed']}, {floor_label(run.get('learner_overrides'))}"
        style = {"color": greys[i % len(greys)], "lw": 0.8, "ls": ("-", "--", ":")[j % 3]}
        ax[0].plot(up, [r["violation_rate"] for r in c], label=label, **style)
        ax[1].plot(up, [r["lambda2"] for r in c], label=label, **style)
    for name, run in runs.items():
        c = [r for r in run["curve"] if r["updates"] > 0]
        up = [r["updates"] for r in c]
        label = f"{name}: seed {run['seed']}, {floor_label(run['learner_overrides'])}"
        (line,) = ax[0].plot(up, [r["violation_rate"] for r in c], lw=1.0, label=label)
        col = line.get_color()
        ax[1].plot(up, [r["lambda2"] for r in c], color=col, lw=1.0, label=f"{label}: λ2(s, z)")
        ax[1].plot(
            up, [r["lambda2_floor"] for r in c], color=col, lw=1.0, ls=":", label=f"{label}: floor"
        )
    ax[0].axhline(0.088, color="k", lw=0.8, ls="--")
    ax[0].set(
        xlabel="updates",
        ylabel="violation rate per 1000 env steps",
        title="posture task (dashed: the bar 0.088)",
    )
    ax[1].set(xlabel="updates", ylabel="λ2", title="λ2's network mean (solid) and floor (dotted)")
    for x in ax:
        x.legend(fontsize=7)
    fig.tight_layout()
    a.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.png, dpi=110)
    print(
        "RESULT",
        json.dumps(
            {
                k: {kk: v for kk, v in r.items() if kk not in ("curve", "skills_eval")}
                for k, r in runs.items()
            }
        ),
    )


if __name__ == "__main__":
    main()
