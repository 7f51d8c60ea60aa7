"""The repertoire service over real Zenoh: commits from two clients, samples in the archive's
support, restore after SIGKILL."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

from proto import codec
from proto import ursa_pb2 as pb
from services.common.bus import query_one
from services.stack import running_stack, wait_for
from ursa.kde import whitening_matrix

pytestmark = pytest.mark.slow


def _features(cid: str, seed: int, n: int, center: tuple[float, float]) -> bytes:
    # positions inside the point env's arena, sent as a collector: the repertoire refuses
    # features outside the declared box and from anyone but a collector (ursa.bounds)
    pts = np.random.default_rng(seed).normal(center, 0.1, (n, 2)).clip(-0.95, 0.95)
    pts = pts.astype(np.float32)
    msg = pb.SafeFeatures(
        header=codec.header("test", f"collector/{cid}"),
        collector_id=cid,
        features=codec.to_array(pts),
    )
    return codec.encode(msg)


def _snapshot(session, topics) -> pb.RepertoireSnapshot | None:  # type: ignore[no-untyped-def]
    return query_one(session, topics.snapshot, pb.RepertoireSnapshot, timeout_s=2.0)


def test_two_clients_commit_sample_and_restore_after_sigkill(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        st.start_router()
        st.start("repertoire", "services.repertoire", "--save-every-s", "1")
        s1, s2 = st.session(), st.session()
        wait_for(lambda: _snapshot(s1, st.topics), 60, "the repertoire to answer")
        # two clients, two separate clusters of safe features
        for i in range(4):
            s1.put(st.topics.features("client1"), _features("client1", 10 + i, 30, (-0.5, 0.0)))
            s2.put(st.topics.features("client2"), _features("client2", 20 + i, 30, (0.5, 0.0)))

        def full() -> pb.RepertoireSnapshot | None:
            snap = _snapshot(s1, st.topics)
            return snap if snap is not None and snap.commits >= 240 else None

        snap = wait_for(full, 30, "240 commits")
        skills = codec.from_array(snap.skills)
        assert len(skills) == 240  # tiny preset: N_R = 300, nothing evicted yet
        assert (skills[:, 0] < 0).sum() == 120 and (skills[:, 0] > 0).sum() == 120

        req = pb.SkillRequest(header=codec.header("test", "client/1"), n=256, has_seed=True, seed=3)
        reply = query_one(s2, st.topics.sample, pb.SkillReply, codec.encode(req))
        assert reply is not None and not reply.error
        samples = codec.from_array(reply.skills)
        assert samples.shape == (256, 2)
        # every sample lies within a few kernel widths of a stored skill (KDE support)
        a = whitening_matrix(codec.from_array(snap.cov))
        d = np.linalg.norm((samples[:, None, :] - skills[None]) @ a.T, axis=-1).min(1)
        assert d.max() < 5.0, d.max()
        # both clusters are sampled, nothing in the empty middle
        assert (samples[:, 0] < -0.3).sum() > 60 and (samples[:, 0] > 0.3).sum() > 60
        again = query_one(s1, st.topics.sample, pb.SkillReply, codec.encode(req))
        assert again is not None
        np.testing.assert_array_equal(codec.from_array(again.skills), samples)  # seeded

        bad = pb.SkillRequest(header=codec.header("test", "client/1"), n=0)
        assert query_one(s1, st.topics.sample, pb.SkillReply, codec.encode(bad)) is None

        ids = codec.from_array(snap.ids).copy()
        wait_for(lambda: (st.run_dir / "repertoire" / "archive.npz").exists(), 10, "a save")
        time.sleep(1.5)  # one more save after the last commit
        st.procs["repertoire"].kill(signal.SIGKILL)
        st.procs["repertoire"].popen.wait(10)
        st.start("repertoire", "services.repertoire", "--save-every-s", "1")

        def restored() -> pb.RepertoireSnapshot | None:
            snap2 = _snapshot(s1, st.topics)
            return snap2 if snap2 is not None and snap2.header.stamp > snap.header.stamp else None

        snap2 = wait_for(restored, 60, "the restarted repertoire")
        np.testing.assert_array_equal(codec.from_array(snap2.ids), ids)
        np.testing.assert_array_equal(codec.from_array(snap2.skills), skills)
        assert snap2.commits == snap.commits
        s1.close()
        s2.close()
