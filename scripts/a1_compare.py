"""URSA against DayDreamer on the A1 forward task (§5.2, Figures 4 and 5): collects serial runs
of both methods (``scripts/a1_serial.py --out``), their coverage evaluations (``ursa eval
diversity URSA_RUN --baseline DD_RUN``, one per seed) and one damage evaluation over all runs
(``ursa eval damage URSA_RUNS --baseline DD_RUNS``) into one JSON, and draws the two methods'
violation rates against training time.

    .venv/bin/python scripts/a1_compare.py --ursa S0.json [S1.json ...] --daydreamer D0.json \
        [...] --diversity DIV0/diversity.json [...] --damage DMG/damage.json \
        --json docs/results/a1_forward_vs_daydreamer.json \
        --png docs/figures/a1_forward_vs_daydreamer_curves.png
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

from a1_floor_figure import summarise  # the one definition of the last-15-minutes window


def curve_summary(d: dict[str, Any]) -> dict[str, Any]:
    """Updates, minutes and violation windows of one ``a1_serial.py`` output."""
    rows = d["rows"]
    trained = [r for r in rows if r["updates"] > 0]
    safe_from = next((r["updates"] for r in trained if r["violation_rate"] <= 0.088), None)
    return {
        "seed": d["seed"],
        "updates": d["updates"],
        "env_steps": d["env_steps"],
        "minutes": round(d["seconds"] / 60, 1),
        "violation_last_15_min": summarise(rows, d["seconds"])["violation_last_15_min"],
        "violation_max_after_safe": (
            None
            if safe_from is None
            else max(r["violation_rate"] for r in trained if r["updates"] >= safe_from)
        ),
        "first_safe_window_updates": safe_from,
        "rescues": rows[-1]["rescues"],
        "learner_overrides": d.get("learner_overrides", {}),
    }


def _med(xs: list[float]) -> dict[str, float]:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ursa", nargs="+", type=Path, required=True)
    ap.add_argument("--daydreamer", nargs="+", type=Path, required=True)
    ap.add_argument("--diversity", nargs="+", type=Path, default=[])
    ap.add_argument("--damage", type=Path, default=None)
    ap.add_argument("--machine", default="")
    ap.add_argument("--label", default="", help="what the URSA runs set, for the figure's title")
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--png", type=Path, required=True)
    a = ap.parse_args()

    curves = {
        "ursa": [json.loads(p.read_text()) for p in a.ursa],
        "daydreamer": [json.loads(p.read_text()) for p in a.daydreamer],
    }
    training = {m: [curve_summary(d) for d in ds] for m, ds in curves.items()}
    coverage: list[dict[str, Any]] = []
    for p in a.diversity:
        dv = json.loads(p.read_text())
        entry: dict[str, Any] = {"source": str(p)}
        for label, r in dv["runs"].items():
            entry[label] = {
                k: r.get(k)
                for k in (
                    "name",
                    "updates",
                    "executions",
                    "safe_executions",
                    "covered_cells",
                    "safe_covered_cells",
                    "return_mean",
                    "violation_rate_mean",
                    "within_delta_fraction",
                )
            }
        entry["safe_ratio"] = dv.get("safe_ratio")
        coverage.append(entry)
    out: dict[str, Any] = {
        "machine": a.machine,
        "label": a.label,
        "commands": [
            "scripts/a1_serial.py --preset cpu --seed S --updates 100000 --minutes M "
            "[--set mode='\"daydreamer\"'] [--set LEARNER_OVERRIDES] --out RUN.json "
            "--run-dir RUN (each run's overrides under training)",
            "ursa eval diversity URSA_RUN --baseline DD_RUN --skills 30 --out DIV",
            "ursa eval damage URSA_RUN... --baseline DD_RUN... --skills 10 --fresh 3 --out DMG",
        ],
        "training": training,
        "coverage": coverage,
    }
    if coverage:
        out["safe_covered_cells"] = {
            lab: _med([c[lab]["safe_covered_cells"] for c in coverage])
            for lab in ("ursa", "baseline", "random")
            if all(lab in c for c in coverage)
        }
    if a.damage is not None:
        dm = json.loads(a.damage.read_text())
        stats = dm["stats"]
        wins = {
            sc: stats["ursa"][sc]["median"] >= stats["baseline"][sc]["median"]
            for sc in stats["ursa"]
            if sc in stats.get("baseline", {}) and sc != "intact"
        }
        out["damage"] = {
            "source": str(a.damage),
            "skills_tried": dm["skills_tried"],
            "fresh_trials": dm["fresh_trials"],
            "steps": dm["steps"],
            "stats": stats,
            "ursa_at_least_daydreamer": wins,
            "damage_wins": sum(wins.values()),
        }
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 1, figsize=(8, 4))
    colours = {"ursa": "tab:blue", "daydreamer": "tab:orange"}
    for method, ds in curves.items():
        for d in ds:
            rows = d["rows"]
            ax.plot(
                [r["t"] / 60 for r in rows],
                [r["violation_rate"] for r in rows],
                color=colours[method],
                lw=1.0,
                alpha=0.9 if d["seed"] == 0 else 0.5,
                label=f"{method}, seed {d['seed']} ({d['updates']} updates)",
            )
    ax.axhline(0.088, color="k", lw=0.8, ls="--")
    ax.axhline(0.876, color="0.5", lw=0.8, ls=":")
    ax.set(
        xlabel="minutes (serial loop, one core each)",
        ylabel="violation rate per 1000 env steps",
        title=f"A1 forward task{(' (URSA: ' + a.label + ')') if a.label else ''}: "
        "dashed the bar 0.088, dotted random 0.876",
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    a.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.png, dpi=110)
    print("RESULT", json.dumps({k: v for k, v in out.items() if k in ("training",)}))
    if "damage" in out:
        print("damage_wins", out["damage"]["damage_wins"])
    if "safe_covered_cells" in out:
        print("safe_covered_cells", json.dumps(out["safe_covered_cells"]))


if __name__ == "__main__":
    main()
