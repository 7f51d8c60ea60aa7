"""Safety statistics of a uniformly random policy on a collector's environment, measured the way
collectors measure them (fraction of unsafe steps, rescues), for comparison with a run.

    .venv/bin/python scripts/random_policy_stats.py --preset small --env a1 --steps 6000
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from ursa.config import build_env, preset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--preset", default="small", choices=["tiny", "point", "small", "cpu", "paper"])
    ap.add_argument("--env", default="a1", choices=["a1", "point"])
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    cfg = preset(a.preset, a.env)  # type: ignore[arg-type]
    env = build_env(cfg, seed=a.seed)
    env.reset(seed=a.seed)
    rng = np.random.default_rng(a.seed)
    unsafe = np.zeros(a.steps, bool)
    ret = 0.0
    rescues = 0
    for t in range(a.steps):
        _, r, _, _, info = env.step(rng.uniform(-1, 1, env.act_dim))
        unsafe[t] = not info["safe"]
        ret += r
        rescues = int(info.get("rescues", 0))
    env.close()
    print(
        json.dumps(
            {
                "env": a.env,
                "steps": a.steps,
                "violation_rate": float(unsafe.mean()),
                "rescues": rescues,
                "rescues_per_1000_steps": 1000 * rescues / a.steps,
                "return_per_step": ret / a.steps,
            }
        )
    )


if __name__ == "__main__":
    main()
