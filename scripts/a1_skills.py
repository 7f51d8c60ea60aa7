"""Execute K KDE skills of an A1 run in the real env and print how many land within δ (the
issue-20 bar for the posture task with provided velocity features: ≥ 50 % of 50 skills), by the
protocol of the point-env learning tests (``tests/ursa/learner/test_learning.py``): skills drawn
from the run's repertoire KDE, each executed for T env steps in turn without resets
(``ursa.serial.evaluate_skills``, ``ursa.scoring``'s rule: sampled actions, the first fifth of
the steps settling), distances in the metric of δ; uniformly random actions on the same skills as
the floor.

    .venv/bin/python scripts/a1_skills.py RUN_DIR [--skills 50] [--out result.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--skills", type=int, default=50)
    ap.add_argument("--steps", type=int, default=0, help="T (default: the run's skill period)")
    ap.add_argument("--seed", type=int, default=11, help="env seed of the evaluation")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()

    import numpy as np

    from ursa.eval.loading import load_run
    from ursa.serial import evaluate_skills
    from ursa.threads import limit_threads

    limit_threads()
    run = load_run(a.run)
    cfg = run.config
    rep = run.require_repertoire()
    steps = a.steps or cfg.collector.skill_period
    skills = rep.sample(a.skills, np.random.default_rng(1))
    cov, delta = rep.cov, rep.delta()
    feat = cfg.feature_input_key
    policy = run.require_policy()
    res = evaluate_skills(policy, run.env(seed=a.seed), skills, steps, cov, feat)
    # random actions' φ: the run's encoder for a learned feature, the feature itself otherwise
    encode = policy.features if cfg.feature == "vae" else None
    rnd = evaluate_skills(None, run.env(seed=a.seed), skills, steps, cov, feat, encode=encode)
    out = {
        "run": str(a.run),
        "updates": run.updates,
        "task": cfg.a1.task,
        "feature": cfg.feature,
        "skills": a.skills,
        "steps": steps,
        "delta": delta,
        "within_delta": float(res.within(delta).mean()),
        "within_delta_random": float(rnd.within(delta).mean()),
        "median_distance_delta_units": float(np.median(res.distance) / delta),
        "violation_rate": float(res.violation_rate.mean()),
        "violation_rate_random": float(rnd.violation_rate.mean()),
        "achieved_spread": np.std(res.achieved, axis=0).tolist(),
        "skills_spread": np.std(skills, axis=0).tolist(),
        # does the achieved feature follow the skill at all (1: in step, 0: unrelated)?
        "correlation": [
            float(np.corrcoef(skills[:, d], res.achieved[:, d])[0, 1])
            for d in range(skills.shape[1])
        ],
        "skill_values": skills.tolist(),
        "achieved_values": res.achieved.tolist(),
    }
    print("RESULT", json.dumps({k: v for k, v in out.items() if not k.endswith("_values")}))
    if a.out is not None:
        a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
