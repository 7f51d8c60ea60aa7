"""Summarise a run directory's metrics over time as a Markdown table (for docs/RESULTS.md),
then one ``RESULT`` line of JSON: each collector's violation rate over the last ``--last-min``
minutes (from its cumulative unsafe-step counter), updates per second, the final replay ratio
and the median over that window of the learner's chunk-latency p50/p99.

.venv/bin/python scripts/run_summary.py runs/<run_id> [--every-min 5] [--last-min 15]
"""

from __future__ import annotations

import argparse
import json
import statistics
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
    ap.add_argument("--last-min", type=float, default=15.0)
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
    start = t1 - a.last_min * 60
    viol = {}
    for c in collectors:
        a0, b = at(series[c], start), series[c][-1]
        if a0 is None:
            a0 = series[c][0]
        n = b["scalars"]["steps"] - a0["scalars"]["steps"]
        viol[c] = (b["scalars"]["unsafe_total"] - a0["scalars"]["unsafe_total"]) / max(n, 1)
    lrows = series.get("learner-main", [])
    window = [r["scalars"] for r in lrows if r["t"] >= start]
    first = next((r for r in lrows if r["scalars"].get("updates", 0) > 0), None)
    last = lrows[-1] if lrows else None
    ups = 0.0
    if first is not None and last is not None and last["t"] > first["t"]:
        ups = (last["scalars"]["updates"] - first["scalars"]["updates"]) / (last["t"] - first["t"])

    def med(key: str) -> float | None:
        vals = [w[key] for w in window if key in w]
        return statistics.median(vals) if vals else None

    result = {
        "minutes": round((t1 - t0) / 60, 1),
        "last_minutes": a.last_min,
        "violation_rate_last": {k: round(v, 4) for k, v in viol.items()},
        "updates": last["scalars"].get("updates") if last else 0,
        "updates_per_s": round(ups, 3),
        "replay_ratio": last["scalars"].get("replay_ratio") if last else None,
        "chunk_latency_p50_ms": med("chunk_latency_p50_ms"),
        "chunk_latency_p99_ms": med("chunk_latency_p99_ms"),
    }
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
