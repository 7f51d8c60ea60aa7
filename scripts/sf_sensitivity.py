"""Does a trained run's SF critic m = (1 − γ)ψ(s, z) depend on the skill z and on the state s?
Model states along real trajectories of the trained policy (4 KDE skills, every 5th step after
the first 10), m for 16 KDE skills at each, all in δ's whitened metric. Printed: the std of m
over skills and over states, the skills' own std and the mean ‖m − z‖ in δ units.

The skill term of the actor's objective reaches the actions only through m's dependence on the
imagined states: a critic flat in s gives the actor no direction towards a skill. The point
recipe's seed 0 (3000 updates): 0.22 over states (δ = 0.79); the A1 ``cpu`` variants of
docs/learner.md ("The A1 actor ignores its skill"): 0.01–0.05 (δ 1.0–1.4).

    .venv/bin/python scripts/sf_sensitivity.py RUN_DIR [--skills 16]
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
    ap.add_argument("--seed", type=int, default=5, help="env seed")
    a = ap.parse_args()

    import numpy as np
    import torch

    from ursa import kde
    from ursa.agent import joint_input
    from ursa.eval.loading import load_learner, load_run, read_checkpoint
    from ursa.serial import evaluate_skills
    from ursa.threads import limit_threads

    limit_threads()
    run = load_run(a.run)
    cfg = run.config
    rep = run.require_repertoire()
    skills = rep.sample(a.skills, np.random.default_rng(0))
    steps = 125 if cfg.env == "a1" else 50
    res = evaluate_skills(
        run.require_policy(),
        run.env(seed=a.seed),
        skills[:4],
        steps,
        rep.cov,
        cfg.feature_input_key,
        record=True,
    )
    assert res.obs is not None and res.actions is not None
    learner = load_learner(cfg, read_checkpoint(a.run / "checkpoints" / "learner.pt"))
    k, t = res.obs.shape[:2]
    first = np.zeros((k, t), bool)
    first[:, 0] = True
    feat = learner.posterior_feats({"obs": res.obs, "action": res.actions, "is_first": first})
    feat = feat[:, 10:].reshape(-1, feat.shape[-1])[::5]
    n = feat.shape[0]
    w = torch.as_tensor(kde.whitening_matrix(kde.regularize_cov(rep.cov)), dtype=torch.float32)
    ms = []
    with torch.no_grad():
        for z in skills:
            sk = torch.as_tensor(np.tile(z, (n, 1)), dtype=torch.float32)
            sf = learner.critics.online(joint_input(feat, sk), sk).sf
            assert sf is not None, "a run without skills has no SF critic"
            ms.append(sf @ w.T)
    m = torch.stack(ms)  # (K, N, D), whitened
    zw = torch.as_tensor(skills, dtype=torch.float32) @ w.T
    delta = float(rep.delta())
    out = {
        "run": str(a.run),
        "updates": run.updates,
        "states": n,
        "delta": delta,
        "std_over_skills": float(m.std(0).mean()),
        "std_over_states": float(m.std(1).mean()),
        "skills_std": float(zw.std(0).mean()),
        "mean_distance_delta_units": float((m - zw[:, None]).norm(dim=-1).mean() / delta),
    }
    print("RESULT", json.dumps(out))


if __name__ == "__main__":
    main()
