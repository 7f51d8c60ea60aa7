"""Summarise a run directory's metrics over time as a Markdown table (for docs/RESULTS.md).

.venv/bin/python scripts/run_summary.py runs/<run_id> [--every-min 5]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def load(path: Path) -> list[dict]:  # type: ignore[type-arg]
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue  # a line cut by a kill
    return rows


def at(rows: list[dict], t: float) -> dict | None:  # type: ignore[type-arg]
    best = None
    for r in rows:
        if r["t"] <= t:
            best = r
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("run", type=Path)
    ap.add_argument("--every-min", type=float, default=5.0)
    a = ap.parse_args()
    m = a.run / "metrics"
    series = {p.stem: load(p) for p in sorted(m.glob("*.jsonl"))}
    collectors = [k for k in series if k.startswith("collector-")]
    t0 = min(r["t"] for rows in series.values() for r in rows[:1])
    t1 = max(r["t"] for rows in series.values() for r in rows[-1:])
    print(
        "| minutes | env steps | updates | violation rate (per collector) | rescues | "
        "repertoire size | δ | entropy bound | replay ratio |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    t = t0
    while True:
        t = min(t + a.every_min * 60, t1)
        lr = at(series.get("learner-main", []), t)
        rr = at(series.get("repertoire-main", []), t)
        cs = [at(series[c], t) for c in collectors]
        steps = sum(int(c["scalars"]["steps"]) for c in cs if c)
        viol = " / ".join(f"{c['scalars']['violation_rate']:.3f}" for c in cs if c)
        resc = sum(int(c["scalars"]["rescues"]) for c in cs if c)
        ls = lr["scalars"] if lr else {}
        rs = rr["scalars"] if rr else {}
        print(
            f"| {(t - t0) / 60:.0f} | {steps} | {ls.get('updates', 0):.0f} | {viol} | {resc} | "
            f"{rs.get('size', 0):.0f} | {rs.get('delta', 0):.3f} | "
            f"{rs.get('entropy_bound', 0):.3f} | {ls.get('replay_ratio', 0):.2f} |"
        )
        if t >= t1:
            break


if __name__ == "__main__":
    main()
