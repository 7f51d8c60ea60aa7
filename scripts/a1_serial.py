"""Train URSA on the A1 in one process (:class:`ursa.serial.SerialLoop`, the services'
reference behaviour at an exact replay ratio) and print the learning curve: violation rate of
the acting policy per window of env steps, updates, the actor's entropy, the multipliers and
the fraction of imagined skills within δ. Used to choose the A1's CPU recipe (docs/learner.md):
every variant trains on one core (one torch thread), so two run side by side.

    .venv/bin/python scripts/a1_serial.py --seed 0 --updates 1200 \
        --set imag_starts=128 compute_dtype=float32 --out /tmp/a1-s0.json

A uniformly random policy's violation rate on the A1 is 0.876 (scripts/random_policy_stats.py).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _parse_sets(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            try:  # Python literals: True, False, None, tuples
                out[key] = ast.literal_eval(value)
            except (ValueError, SyntaxError):
                out[key] = value
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="small")
    ap.add_argument("--feature", default="vae", help="vae (learned φ) or velocity (provided)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--updates", type=int, default=1200, help="stop after this many updates")
    ap.add_argument("--minutes", type=float, default=60.0, help="or after this long")
    ap.add_argument("--prefill", type=int, default=2000)
    ap.add_argument("--window", type=int, default=1000, help="env steps per printed row")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="learner fields")
    ap.add_argument("--a1", nargs="*", default=[], metavar="FIELD=VALUE", help="A1Config fields")
    ap.add_argument(
        "--collector", nargs="*", default=[], metavar="FIELD=VALUE", help="CollectorConfig fields"
    )
    ap.add_argument("--out", type=Path, default=None, help="the curve as JSON")
    ap.add_argument("--run-dir", type=Path, default=None, help="save the run directory here")
    a = ap.parse_args()

    import numpy as np
    import torch  # noqa: F401 - loaded first, so that its pool is limited too

    from ursa.config import preset
    from ursa.eval.loading import SerialRecorder, make_serial_loop, save_serial_run
    from ursa.threads import limit_threads

    limit_threads()
    cfg = preset(a.preset, "a1", a.feature)  # type: ignore[arg-type]
    learner = _parse_sets(a.set)
    cfg = dataclasses.replace(cfg, learner=dataclasses.replace(cfg.learner, **learner))
    if a.a1:
        cfg = dataclasses.replace(cfg, a1=dataclasses.replace(cfg.a1, **_parse_sets(a.a1)))
    if a.collector:
        col = dataclasses.replace(cfg.collector, **_parse_sets(a.collector))
        cfg = dataclasses.replace(cfg, collector=col)
    loop = make_serial_loop(cfg, prefill=a.prefill, seed=a.seed, env_seed=a.seed)
    rec = SerialRecorder(loop) if a.run_dir is not None else None
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    state = {"steps": 0, "unsafe": 0, "hist": 0}

    def window(lp: Any) -> None:
        if rec is not None:
            rec(lp)
        n = max(lp.env_steps - state["steps"], 1)
        viol = (lp.unsafe_steps - state["unsafe"]) / n
        hist = lp.history[state["hist"] :]
        state.update(steps=lp.env_steps, unsafe=lp.unsafe_steps, hist=len(lp.history))

        def mean(key: str) -> float:
            vals = [h[key] for h in hist if key in h]
            return float(np.mean(vals)) if vals else float("nan")

        row = {
            "t": time.perf_counter() - t0,
            "env_steps": lp.env_steps,
            "updates": lp.learner.updates,
            "violation_rate": viol,
            "rescues": int(getattr(lp.env, "rescues", 0)),
            "entropy": mean("actor/entropy"),
            "lambda1": mean("lambda1/mean"),
            "lambda2": mean("lambda2/mean"),
            "lambda2_floor": mean("lambda2/floor"),
            "within_delta": mean("imag/within_delta"),
            "cost_return": mean("imag/cost_return"),
            "vae_version": lp.learner.vae_version,
        }
        rows.append(row)
        print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}))
        sys.stdout.flush()

    deadline = t0 + a.minutes * 60
    while loop.learner.updates < a.updates and time.perf_counter() < deadline:
        loop.run(a.window, callback=window, callback_every=a.window)
    last = [r for r in rows if r["updates"] > 0][-5:]
    summary = {
        "preset": a.preset,
        "feature": a.feature,
        "seed": a.seed,
        "learner_overrides": learner,
        "a1_overrides": _parse_sets(a.a1),
        "collector_overrides": _parse_sets(a.collector),
        "updates": loop.learner.updates,
        "env_steps": loop.env_steps,
        "seconds": time.perf_counter() - t0,
        "violation_rate_last5": float(np.mean([r["violation_rate"] for r in last])),
        "rows": rows,
    }
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(summary, indent=1))
    if a.run_dir is not None:
        save_serial_run(loop, cfg, a.run_dir, rec)
    print("RESULT", json.dumps({k: v for k, v in summary.items() if k != "rows"}))


if __name__ == "__main__":
    main()
