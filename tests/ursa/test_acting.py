"""A collector's acting loop (``ursa.acting``): records in the world model's convention, chunks
with their first step index, a rescue ends the chunk and skips an index (also on a chunk's first
step), the policy takes over from random acting with a fresh carry, diverged actions are
sanitised and counted."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.ursa.envs.rescued import RescuedPoint
from ursa.acting import RECORD_FIELDS, Acting, ActingConfig, sanitise
from ursa.config import preset
from ursa.envs.point import PointEnv
from ursa.learner import Learner
from ursa.policy import Policy

torch.set_num_threads(1)


def _acting(env: PointEnv, chunk_len: int = 10, **kw: object) -> Acting:
    cfg = preset("tiny", "point")
    pol = Policy(cfg.learner, env.obs_dim, env.act_dim, 2, 2, seed=0)
    ac = ActingConfig(feature="position", skill_period=7, chunk_len=chunk_len, **kw)  # type: ignore[arg-type]
    return Acting(env, pol, ac, np.random.default_rng(0))


def test_records_follow_the_world_models_convention() -> None:
    a = _acting(PointEnv(seed=1), chunk_len=5)
    ref = PointEnv(seed=1)
    ref.reset()
    a.skill = np.array([0.3, -0.2])
    chunks, due, seen = [], [], []
    for _ in range(12):
        due.append(a.skill_due())
        r = a.step(random=True)
        obs, rew, _, _, info = ref.step(r.action)
        chunks += r.chunks
        seen.append((obs, r.action, rew, info["cost"], info["features"]["position"]))
        np.testing.assert_allclose(a.obs, obs)
        assert r.reward == rew
    assert np.flatnonzero(due).tolist() == [0, 7]  # skill_period 7
    assert [c.first_step for c in chunks] == [0, 5] and a.open_records == 2
    c = chunks[1]
    assert sorted(c.data) == sorted(RECORD_FIELDS) and len(c) == 5
    assert c.data["obs"].dtype == np.float32 and c.data["safe"].dtype == np.bool_
    # record t: the observation after action t, with its reward, cost and feature input
    for t, (obs, act, rew, cost, feat) in enumerate(seen[5:10]):
        np.testing.assert_allclose(c.data["obs"][t], obs, rtol=1e-6)
        np.testing.assert_allclose(c.data["action"][t], act, rtol=1e-6)
        np.testing.assert_allclose(c.data["features"][t], feat, rtol=1e-6)
        assert c.data["reward"][t] == np.float32(rew) and c.data["cost"][t] == np.float32(cost)
    np.testing.assert_allclose(c.data["skill"], np.tile([0.3, -0.2], (5, 1)), rtol=1e-6)
    np.testing.assert_array_equal(c.safe_features, c.data["features"][c.data["safe"]])
    last = a.flush()
    assert [x.first_step for x in last] == [10] and len(last[0]) == 2 and a.flush() == []
    assert a.step_count == 12 and a.open_records == 0


def test_a_rescue_ends_the_chunk_and_skips_an_index() -> None:
    # rescues mid-chunk (step 3) and on what would be a chunk's first step (13 after 3..12)
    a = _acting(RescuedPoint({3, 13}), chunk_len=10)
    chunks = []
    for _ in range(30):
        chunks += a.step(random=True).chunks
    chunks += a.flush()
    starts = [(c.first_step, len(c)) for c in chunks]
    # 0..2 | rescue: 3..12 become indices 4..13 | rescue at 13: indices 15..24, then 25..31
    assert starts == [(0, 3), (4, 10), (15, 10), (25, 7)]
    assert a.step_offset == 2 and a.step_count == 30


def test_policy_takes_over_with_a_fresh_carry_and_sanitised_actions() -> None:
    env = PointEnv(seed=0)
    a = _acting(env)
    calls: list[int] = []
    orig = a.policy.initial_carry

    def spy():  # type: ignore[no-untyped-def]
        calls.append(a.step_count)
        return orig()

    a.policy.initial_carry = spy  # type: ignore[method-assign]
    for _ in range(3):
        a.step(random=True)
    a.step()
    assert calls == [3]  # a carry from the policy's current weights when it takes over
    a.step()
    assert calls == [3]
    # a diverged actor: every action is mapped into the box and counted
    cfg = preset("tiny", "point")
    learner = Learner(cfg.learner, env.obs_dim, env.act_dim, 2)
    with torch.no_grad():
        for p in learner.actor.parameters():
            p.fill_(float("nan"))
    a.policy.load_weights_bytes(learner.policy_weights_bytes(), version=1)
    for i in range(3):
        r = a.step()
        assert np.all(r.action == 0.0) and a.nonfinite_actions == i + 1
    assert np.all(np.isfinite(a.obs))
    fixed, bad = sanitise(np.array([np.nan, np.inf, -np.inf, 0.5]))
    np.testing.assert_array_equal(fixed, [0.0, 1.0, -1.0, 0.5])
    assert bad and not sanitise(np.zeros(2))[1]


def test_stamps_and_pose_are_recorded_when_asked() -> None:
    a = _acting(PointEnv(seed=0), chunk_len=4, stamps=True)
    chunks = []
    for _ in range(4):
        chunks += a.step(random=True).chunks
    (c,) = chunks
    assert c.data["stamp"].dtype == np.float64 and np.all(np.diff(c.data["stamp"]) >= 0)
    assert "base_pose" not in c.data  # the point env reports no pose


def test_random_actions_fill_the_box_scaled_by_random_scale() -> None:
    full = _acting(PointEnv(seed=1))
    narrow = _acting(PointEnv(seed=1), random_scale=0.2)
    a = np.array([full.step(random=True).action for _ in range(400)])
    b = np.array([narrow.step(random=True).action for _ in range(400)])
    # same generator, same draws: the scaled actions are the full-box ones times s
    np.testing.assert_allclose(b, 0.2 * a)
    assert np.abs(a).max() > 0.95 and np.abs(b).max() <= 0.2
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="random_scale"):
            ActingConfig(feature="position", random_scale=bad)


def test_archive_features_are_means_of_whole_safe_blocks() -> None:
    from ursa.acting import Chunk
    from ursa.config import CollectorConfig

    feats = np.arange(14, dtype=np.float32).reshape(7, 2)  # rows [0,1], [2,3], ... [12,13]
    safe = np.array([True, True, True, False, True, True, True])
    c = Chunk(0, {"features": feats, "safe": safe})
    np.testing.assert_array_equal(c.archive_features(1), feats[safe])
    # blocks of 2: [0,1] safe -> mean of rows 0,1; [2,3] has an unsafe step; [4,5] safe;
    # row 6 is a partial block, dropped
    np.testing.assert_allclose(c.archive_features(2), [[1.0, 2.0], [9.0, 10.0]])
    # blocks of 3: rows 0-2 safe -> [2, 3]; rows 3-5 hold the unsafe step
    np.testing.assert_allclose(c.archive_features(3), [[2.0, 3.0]])
    assert c.archive_features(3).dtype == np.float32
    assert c.archive_features(8).shape == (0, 2)
    with pytest.raises(ValueError):
        c.archive_features(0)
    with pytest.raises(ValueError, match="divide"):
        CollectorConfig(chunk_len=50, archive_window=20)
    assert CollectorConfig(chunk_len=50, archive_window=25).archive_window == 25
