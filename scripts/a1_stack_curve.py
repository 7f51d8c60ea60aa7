"""The training curve of an ``ursa up`` run in the format of ``scripts/a1_serial.py --out``, so
that ``scripts/a1_floor_figure.py --run`` and ``scripts/a1_skills.py`` treat a stack run as a
serial one: per window of ``--window`` env steps pooled over the collectors, the violation rate
(from their cumulative ``steps`` / ``unsafe_total`` counters in ``metrics/collector-*.jsonl``)
and the learner's means over the window (``metrics/learner-main.jsonl``); the config
overrides against the run's preset, from its saved config.

    .venv/bin/python scripts/a1_stack_curve.py runs/<run_id> --out CURVE.json [--window 1000]
"""

from __future__ import annotations

import argparse
import bisect
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ursa.config import preset  # noqa: E402
from ursa.eval.loading import iter_metrics, load_config  # noqa: E402

LEARNER_KEYS = {
    "entropy": "actor/entropy",
    "lambda1": "lambda1/mean",
    "lambda2": "lambda2/mean",
    "lambda2_floor": "lambda2/floor",
    "within_delta": "imag/within_delta",
    "cost_return": "imag/cost_return",
}


def overrides(cfg: Any, base: Any) -> dict[str, Any]:
    """The fields of dataclass ``cfg`` that differ from ``base``'s."""
    return {
        f.name: getattr(cfg, f.name)
        for f in dataclasses.fields(cfg)
        if getattr(cfg, f.name) != getattr(base, f.name)
    }


def pooled(collectors: list[list[dict[str, Any]]]) -> list[tuple[float, float, float]]:
    """(t, env steps, unsafe steps) summed over the collectors at each of their stats rows,
    each collector at its latest row up to t (a collector not yet seen counts 0)."""
    times = sorted({r["t"] for rows in collectors for r in rows})
    stamps = [[r["t"] for r in rows] for rows in collectors]
    out = []
    for t in times:
        steps = unsafe = 0.0
        for rows, ts in zip(collectors, stamps, strict=True):
            i = bisect.bisect_right(ts, t) - 1
            if i >= 0:
                steps += rows[i]["scalars"]["steps"]
                unsafe += rows[i]["scalars"]["unsafe_total"]
        out.append((t, steps, unsafe))
    return out


def curve(
    collectors: list[list[dict[str, Any]]], learner: list[dict[str, Any]], window: int
) -> list[dict[str, Any]]:
    """Rows of :mod:`scripts.a1_serial`'s curve, one per ``window`` pooled env steps."""
    pts = pooled(collectors)
    if not pts:
        return []
    t0 = pts[0][0]
    lt = [r["t"] for r in learner]
    rows: list[dict[str, Any]] = []
    start = pts[0]
    for t, steps, unsafe in pts[1:]:
        if steps - start[1] < window:
            continue
        lo, hi = bisect.bisect_right(lt, start[0]), bisect.bisect_right(lt, t)
        span = learner[lo:hi]
        last = learner[hi - 1]["scalars"] if hi > 0 else {}
        row: dict[str, Any] = {
            "t": t - t0,
            "env_steps": int(steps),
            "updates": int(last.get("updates", 0)),
            "violation_rate": (unsafe - start[2]) / (steps - start[1]),
        }
        for name, key in LEARNER_KEYS.items():
            vals = [r["scalars"][key] for r in span if key in r["scalars"]]
            row[name] = sum(vals) / len(vals) if vals else math.nan
        rows.append(row)
        start = (t, steps, unsafe)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--window", type=int, default=1000, help="pooled env steps per row")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    by_collector: dict[str, list[dict[str, Any]]] = {}
    learner: list[dict[str, Any]] = []
    for row in iter_metrics(a.run):
        if row["service"] == "collector" and row["id"].startswith("c"):  # not the evaluator
            by_collector.setdefault(row["id"], []).append(row)
        elif row["service"] == "learner":
            learner.append(row)
    collectors = [by_collector[k] for k in sorted(by_collector)]
    cfg = load_config(a.run)
    base = preset(cfg.preset, cfg.env, cfg.feature)  # type: ignore[arg-type]
    rows = curve(collectors, learner, a.window)
    ls = learner[-1]["scalars"] if learner else {}
    summary = {
        "run": str(a.run),
        "preset": cfg.preset,
        "feature": cfg.feature,
        "seed": cfg.learner.seed,
        "collectors": len(collectors),
        "learner_overrides": overrides(cfg.learner, base.learner),
        "a1_overrides": overrides(cfg.a1, base.a1),
        "collector_overrides": overrides(cfg.collector, base.collector),
        "updates": int(ls.get("updates", 0)),
        "env_steps": rows[-1]["env_steps"] if rows else 0,
        "seconds": rows[-1]["t"] if rows else 0.0,
        "replay_ratio": ls.get("replay_ratio"),
        "rows": rows,
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(summary, indent=1))
    print("RESULT", json.dumps({k: v for k, v in summary.items() if k != "rows"}))


if __name__ == "__main__":
    main()
