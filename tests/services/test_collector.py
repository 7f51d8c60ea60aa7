"""The collector in-process against a real router: what it does with a diverged policy."""

from __future__ import annotations

import time
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


def test_the_repertoire_is_sent_block_means_of_safe_features(tmp_path: Path) -> None:
    import dataclasses

    from proto import codec
    from proto import ursa_pb2 as pb
    from services.stack import wait_for

    base = preset("tiny", "point")
    col = dataclasses.replace(base.collector, chunk_len=10, archive_window=5)
    cfg = dataclasses.replace(base, collector=col)
    with running_stack(tmp_path) as st:
        st.start_router()
        session = st.session()
        chunks: list[bytes] = []
        feats: list[bytes] = []
        t = st.topics
        subs = [
            session.declare_subscriber(
                t.transitions("w"), lambda s: chunks.append(s.payload.to_bytes())
            ),
            session.declare_subscriber(
                t.features("w"), lambda s: feats.append(s.payload.to_bytes())
            ),
        ]
        time.sleep(1.0)  # the subscriptions reach the router before anything is sent
        c = Collector(
            CollectorArgs(
                core=cfg, bus=st.bus, run=RunConfig("test", st.runs), collector_id="w", max_steps=40
            )
        )
        try:
            c.run()
            wait_for(lambda: len(chunks) >= 4, 30, "4 chunks")
            wait_for(lambda: len(feats) >= 1, 30, "features")
            time.sleep(1.0)
        finally:
            c.close()
        for s in subs:
            s.undeclare()
        session.close()
    want = []
    for raw in chunks:
        ch = codec.decode(pb.TransitionChunk, raw)
        f = codec.from_array(ch.features).reshape(-1, 5, 2)
        safe = codec.from_array(ch.safe).reshape(-1, 5).all(1)
        want.append(f[safe].mean(1))
    got = np.concatenate(
        [codec.from_array(codec.decode(pb.SafeFeatures, r).features) for r in feats]
    )
    np.testing.assert_allclose(got, np.concatenate(want), rtol=1e-5)
    assert len(got) > 0 and len(got) <= 40 // 5
