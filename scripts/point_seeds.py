"""Train the point preset (the learning tests' recipe) for several seeds and judge each run as
the learning tests do (``tests/ursa/learner/test_learning.assess``): KDE skills executed within
δ by the scoring rule of ``ursa.scoring``, the violation rate against random actions', and the
same for one DayDreamer run. Writes a JSON with every seed's numbers and their median/worst.

    .venv/bin/python scripts/point_seeds.py --seeds 0 1 2 3 4 --out docs/results/point_seeds.json

Two seeds train at a time (one process each, one torch thread each).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _one(job: tuple[str, str, int, dict[str, str]]) -> dict[str, Any]:
    import numpy as np
    import torch  # noqa: F401 - loaded first, so that its pool is set too

    from tests import trained
    from tests.ursa.learner.test_learning import assess
    from ursa.eval.loading import SerialRecorder, make_serial_loop, save_serial_run
    from ursa.threads import limit_threads

    limit_threads()
    root, mode, seed, learner = job
    cfg = trained.point_config(mode, seed)  # type: ignore[arg-type]
    if learner:  # a variant of the recipe (e.g. another compute dtype or actor gradient)
        new = dataclasses.replace(cfg.learner, **learner)  # type: ignore[arg-type]
        cfg = dataclasses.replace(cfg, learner=new)
    t0 = time.perf_counter()
    loop = make_serial_loop(cfg, prefill=trained.PREFILL_STEPS, seed=seed)
    rec = SerialRecorder(loop)
    loop.run(trained.ENV_STEPS - loop.env_steps, callback=rec, callback_every=1000)
    run_dir = save_serial_run(loop, cfg, Path(root) / f"{mode}-s{seed}", rec)
    secs = time.perf_counter() - t0
    if mode == "daydreamer":
        return {"mode": mode, "seed": seed, "seconds": secs, "dir": str(run_dir)}
    a = assess(run_dir, f"seed {seed}", recipe=not learner)
    out = {
        "mode": mode,
        "seed": seed,
        "seconds": secs,
        "dir": str(run_dir),
        "delta": a["delta"],
        "within_delta": float(a["eval"].within(a["delta"]).mean()),
        "within_delta_random": float(a["random"].within(a["delta"]).mean()),
        "violation_rate": float(a["eval"].violation_rate.mean()),
        "violation_rate_random": float(a["random"].violation_rate.mean()),
        "skills": np.asarray(a["skills"]).tolist(),
    }
    return out


def _cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo``), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--out", type=Path, default=ROOT / "docs/results/point_seeds.json")
    ap.add_argument("--runs", type=Path, default=Path("/tmp/ursa-point-seeds"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--compute-dtype",
        default=None,
        help="the learner's compute_dtype instead of the recipe's (float32, bfloat16, auto)",
    )
    ap.add_argument(
        "--actor-grad", default=None, help="the learner's actor_grad instead of the recipe's"
    )
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="other learner fields instead of the recipe's (a variant to measure)",
    )
    ap.add_argument("--no-daydreamer", action="store_true", help="skip the DayDreamer run")
    a = ap.parse_args()
    learner: dict[str, Any] = {
        k: v
        for k, v in (("compute_dtype", a.compute_dtype), ("actor_grad", a.actor_grad))
        if v is not None
    }
    for item in a.set:
        key, _, value = item.partition("=")
        learner[key] = json.loads(value) if value[:1] in '-0123456789.tf[{"' else value
    jobs = [(str(a.runs), "ursa-supervised", s, learner) for s in a.seeds]
    if not a.no_daydreamer:
        jobs.append((str(a.runs), "daydreamer", a.seeds[0], learner))
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(a.workers, mp_context=ctx) as ex:
        rows = list(ex.map(_one, jobs))
    ursa = [r for r in rows if r["mode"] != "daydreamer"]
    dd = next((r for r in rows if r["mode"] == "daydreamer"), None)

    import numpy as np

    from tests.ursa.learner.test_learning import EVAL_T
    from ursa.envs.point import PointEnv
    from ursa.eval.loading import load_run
    from ursa.serial import evaluate_skills

    dd_within = []
    ddr = load_run(dd["dir"]) if dd is not None else None
    for r in ursa if ddr is not None else []:  # DayDreamer's policy on every seed's skills
        rep = load_run(r["dir"]).require_repertoire()
        res = evaluate_skills(
            ddr.require_policy(), PointEnv(seed=11), np.asarray(r["skills"]), EVAL_T, rep.cov
        )
        dd_within.append(float(res.within(rep.delta()).mean()))
    within = np.array([r["within_delta"] for r in ursa])
    summary = {
        "seeds": a.seeds,
        "learner_overrides": learner,
        "machine": f"{_cpu_model()}, {multiprocessing.cpu_count()} cores",
        "within_delta": within.tolist(),
        "within_delta_median": float(np.median(within)),
        "within_delta_worst": float(within.min()),
        "within_delta_random": [r["within_delta_random"] for r in ursa],
        "within_delta_daydreamer": dd_within,
        "violation_rate": [r["violation_rate"] for r in ursa],
        "violation_rate_random": [r["violation_rate_random"] for r in ursa],
        "seconds": [r["seconds"] for r in rows],
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
