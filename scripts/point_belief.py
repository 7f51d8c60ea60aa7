"""Why a trained point run misses skills: the world model's belief of φ against the robot's.

Runs the learning tests' evaluation of a run directory (60 KDE skills, T steps each, the scoring
rule of ``ursa.scoring``), replays the real trajectories through the trained learner
(posterior states) and prints, over the settled steps: the φ head's and the decoder's position
error, the SF critic's m = (1 − γ)ψ against the skill and against the real discounted average,
λ1, and for each missed skill where the robot was, where the model believed it was and what the
critic read. docs/learner.md ("Why a seed misses skills") was measured with it.

    .venv/bin/python scripts/point_belief.py RUN_DIR [RUN_DIR ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def belief(run_dir: Path) -> None:
    from tests.ursa.learner.test_learning import assess
    from ursa import kde, scoring
    from ursa.distributions import symexp

    a = assess(run_dir, str(run_dir), recipe=False)
    learner, res, skills, delta = a["learner"], a["eval"], a["skills"], a["delta"]
    k, t = res.obs.shape[:2]
    first = np.zeros((1, k * t), bool)
    first[0, 0] = True
    feat = learner.posterior_feats(
        {"obs": res.obs.reshape(1, k * t, -1), "action": res.actions.reshape(1, k * t, -1),
         "is_first": first}
    )  # fmt: skip
    with torch.no_grad():
        phi = learner.wm.predict(feat)["phi"].numpy().reshape(k, t, -1)
        dec = symexp(learner.wm.decoder(feat)).numpy().reshape(k, t, -1)[..., :2]
    pos = res.obs[..., :2]
    sk = np.repeat(skills[:, None, :], t, 1).reshape(1, k * t, -1)
    m = learner.critic_values(feat, sk)["sf"].reshape(k, t, -1)
    lam1 = learner.multipliers(feat, sk)[0].reshape(k, t)
    gamma = learner.config.discount
    real_m = np.zeros_like(pos)  # discounted average of the real future positions
    acc = pos[:, -1].copy()
    for i in range(t - 1, -1, -1):
        acc = (1 - gamma) * pos[:, i] + gamma * acc
        real_m[:, i] = acc
    s0 = scoring.settle_steps(t)
    mid = slice(s0, t - 60)  # settled, and far enough from the skill's end for real_m
    within = res.within(delta)
    w = kde.whitening_matrix(kde.regularize_cov(a["cov"]))
    sf_err = (m - real_m)[:, mid] ** 2
    rms = lambda x: float(np.sqrt((x[:, s0:] ** 2).sum(-1).mean()))  # noqa: E731
    print(f"\n{run_dir}: within δ {within.mean():.3f} (δ {delta:.3f})")
    print(
        f"  position error rms per step: φ head {rms(phi - pos):.4f}, decoder {rms(dec - pos):.4f}"
    )
    print(f"  SF m − real discounted average: rms {float(np.sqrt(sf_err.sum(-1).mean())):.4f}")
    dist_m = np.linalg.norm(((m - skills[:, None]) @ w.T)[:, mid], axis=-1).mean()
    print(
        f"  ‖m − z‖_Σ along the settled steps {dist_m:.3f}; real distance {res.distance.mean():.3f}"
    )
    print(f"  λ1 along the settled steps {lam1[:, mid].mean():.3f}")
    for i in np.where(~within)[0]:
        print(
            f"  miss z={skills[i].round(2)} achieved={res.achieved[i].round(2)} "
            f"d={res.distance[i]:.2f} critic m={m[i, mid].mean(0).round(2)} "
            f"φ head error={(phi - pos)[i, s0:].mean(0).round(3)} λ1={lam1[i, mid].mean():.2f}"
        )


if __name__ == "__main__":
    torch.set_num_threads(1)
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for arg in sys.argv[1:]:
        belief(Path(arg))
