"""The collector in-process against a real router: what it does with a diverged policy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from services.collector.service import Collector, CollectorArgs
from services.common.config import RunConfig
from services.stack import running_stack
from ursa.config import preset
from ursa.learner import Learner


def test_non_finite_policy_actions_are_sanitised_and_counted(tmp_path: Path) -> None:
    cfg = preset("tiny", "point")
    with running_stack(tmp_path) as st:
        st.start_router()
        c = Collector(
            CollectorArgs(
                core=cfg,
                bus=st.bus,
                run=RunConfig("test", st.runs),
                collector_id="nan",
                max_steps=3,
            )
        )
        try:
            env = c.env
            assert c.acting.env is env and c.acting.policy is c.policy
            learner = Learner(cfg.learner, env.obs_dim, env.act_dim, 2)
            with torch.no_grad():
                for p in learner.actor.parameters():
                    p.fill_(float("nan"))  # a diverged actor
            c.policy.load_weights_bytes(learner.policy_weights_bytes(), version=1)
            c.policy_version = 1
            c.run()  # acts with the diverged weights: 3 steps, then the stats
            assert c.acting.nonfinite_actions == 3 and np.all(np.isfinite(c.acting.obs))
        finally:
            c.close()
