"""Malformed, wrong-version or inconsistent payloads are counted and dropped; services go on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from proto import codec
from proto import ursa_pb2 as pb
from services.stack import StatsWatcher, running_stack, wait_for

pytestmark = pytest.mark.slow


def test_services_count_and_drop_bad_payloads(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        st.start_router()
        rep = st.start("repertoire", "services.repertoire")
        learner = st.start("learner", "services.learner")
        session = st.session()
        watcher = StatsWatcher(session, st.topics)
        wait_for(
            lambda: watcher.get("learner", "main") and watcher.get("repertoire", "main"),
            60,
            "learner and repertoire stats",
        )

        wrong_version = pb.SafeFeatures(
            header=codec.header(st.run_id, "evil/0"),
            features=codec.to_array(np.zeros((2, 2), np.float32)),
        )
        wrong_version.header.schema_version = 99
        wrong_dim = pb.SafeFeatures(
            header=codec.header(st.run_id, "evil/0"),
            features=codec.to_array(np.zeros((2, 7), np.float32)),
        )
        bad_array = pb.TransitionChunk(
            header=codec.header(st.run_id, "evil/0"),
            collector_id="evil",
            obs=pb.Array(dtype="<f4", shape=[5, 6], data=b"\0" * 7),
        )
        rows_mismatch = pb.TransitionChunk(
            header=codec.header(st.run_id, "evil/0"),
            collector_id="evil",
            obs=codec.to_array(np.zeros((5, 6), np.float32)),
            action=codec.to_array(np.zeros((4, 2), np.float32)),
        )
        for payload in (
            b"garbage\xff\xff",
            wrong_version.SerializeToString(),
            wrong_dim.SerializeToString(),
        ):
            session.put(st.topics.features("evil"), payload)
        for payload in (
            b"\x0a\xff",
            bad_array.SerializeToString(),
            rows_mismatch.SerializeToString(),
        ):
            session.put(st.topics.transitions("evil"), payload)

        def dropped(service: str) -> float:
            s = watcher.get(service, "main")
            return s.scalars["dropped_messages"] if s else 0.0

        wait_for(
            lambda: dropped("repertoire") >= 3 and dropped("learner") >= 3,
            30,
            "both services to count the bad payloads",
        )

        # a good payload after the bad ones is still accepted
        good = pb.SafeFeatures(
            header=codec.header(st.run_id, "good/0"),
            collector_id="good",
            features=codec.to_array(
                np.random.default_rng(0).uniform(-1, 1, (50, 2)).astype(np.float32)
            ),
        )
        session.put(st.topics.features("good"), codec.encode(good))
        wait_for(
            lambda: (s := watcher.get("repertoire", "main")) and s.scalars["size"] >= 40,
            30,
            "the good features to be committed",
        )
        assert rep.alive() and learner.alive(), st.logs()
        ls = watcher.get("learner", "main")
        assert ls is not None and ls.scalars["replay_steps"] == 0
        watcher.close()
        session.close()
