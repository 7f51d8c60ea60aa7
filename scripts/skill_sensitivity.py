"""Does a trained policy's action depend on its skill? Along one real trajectory (the policy
acting on a first KDE skill, its action mode), the actor's action mode tanh(μ) at each filtered
state is recomputed for K skills drawn from the run's repertoire KDE. Printed: the std of the
action over the skills (averaged over steps and action dimensions), its std over time on the
first skill, and the mean |action| (near 1: tanh saturated, where no gradient moves it).

A policy that executes skills changes its action with the skill: the point recipe's seed 0
(3000 updates; the learning tests judge it) gives 0.55 over skills (actions in [−1, 1]); the
A1's ``cpu`` variants that stand still for every skill give 0.0015–0.0125
(docs/learner.md).

    .venv/bin/python scripts/skill_sensitivity.py RUN_DIR [--skills 16] [--steps 150]
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
    ap.add_argument("--skills", type=int, default=16)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--seed", type=int, default=5, help="env seed")
    a = ap.parse_args()

    import numpy as np

    from ursa import policy_np
    from ursa.eval.loading import load_run
    from ursa.threads import limit_threads

    limit_threads()
    run = load_run(a.run)
    policy = run.require_policy()
    skills = run.require_repertoire().sample(a.skills, np.random.default_rng(0))
    env = run.env(seed=a.seed)
    obs, _ = env.reset()
    carry = policy.initial_carry()
    rows = []
    for _ in range(a.steps):
        action, carry = policy.act(carry, obs, skills[0], explore=False)
        h, z = carry.h[0], carry.z[0]
        rows.append(
            [
                np.tanh(policy_np.actor_dist(h, z, np.asarray(s, np.float32), policy.params)[0])
                for s in skills
            ]
        )
        obs, *_ = env.step(action)
    acts = np.asarray(rows)  # (steps, K, A)
    over_skills = float(acts.std(1).mean())
    over_time = float(acts[:, 0].std(0).mean())
    out = {
        "run": str(a.run),
        "updates": run.updates,
        "std_over_skills": over_skills,
        "std_over_time": over_time,
        "ratio": over_skills / max(over_time, 1e-12),
        "mean_abs_action": float(np.abs(acts).mean()),
    }
    print("RESULT", json.dumps(out))


if __name__ == "__main__":
    main()
