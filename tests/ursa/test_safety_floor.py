"""λ2's integrating floor (``ursa.safety_floor``): hand-worked averages and steps, and the floor
in the learner (it moves with the real rate, binds only the actor's weight of the cost,
resumes from a checkpoint) and in the serial loop (the rate of the stored steps)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tests.ursa.learner.test_learner import MICRO, _random_replay, _snapshot
from ursa.envs.point import PointEnv
from ursa.learner import Learner
from ursa.safety_floor import ema_rate, floor_step
from ursa.serial import SerialConfig, SerialLoop


def test_ema_rate_hand_worked() -> None:
    # window 2 (α = 1/2): starts at the flags' mean 0.5, then 0.5 → 0.75 (u = 1) → 0.375 (u = 0)
    assert ema_rate(None, np.array([1, 0]), 2) == pytest.approx(0.375)
    # from 0.2, four safe steps with window 4: 0.2 · 0.75⁴
    assert ema_rate(0.2, np.zeros(4, bool), 4) == pytest.approx(0.2 * 0.75**4)
    assert ema_rate(0.3, np.zeros(0), 10) == 0.3
    with pytest.raises(ValueError):
        ema_rate(None, np.zeros(0), 10)


def test_ema_rate_equals_single_steps() -> None:
    rng = np.random.default_rng(0)
    flags = rng.random(500) < 0.2
    ref = 0.7
    for u in flags:
        ref += (float(u) - ref) / 37
    out = 0.7
    for part in np.array_split(flags, [3, 4, 120, 121, 400]):
        out = ema_rate(out, part, 37)
    assert out == pytest.approx(ref, rel=1e-12)


def test_floor_step_integrates_and_clips() -> None:
    assert floor_step(0.5, 0.3, 0.1, 0.5, 1.0) == pytest.approx(0.6)
    assert floor_step(0.5, 0.0, 0.1, 0.5, 1.0) == pytest.approx(0.45)
    assert floor_step(0.01, 0.0, 0.1, 0.5, 1.0) == 0.0
    assert floor_step(0.85, 1.0, 0.0, 0.5, 0.9) == 0.9


def test_learner_floor_moves_with_the_real_rate_and_binds_the_actor_only(
    tmp_path: Path,
) -> None:
    replay = _random_replay()
    snap = _snapshot(np.random.default_rng(0).uniform(-1, 1, size=(300, 2)))
    batch = replay.sample(MICRO.batch_size, MICRO.seq_len, np.random.default_rng(0))
    base = dataclasses.replace(MICRO, mode="ursa-supervised")
    cfg = dataclasses.replace(base, lambda2_floor_lr=0.1, lambda2_floor_target=0.1)
    off = Learner(base, 6, 2, 2).train_step(batch, snap, violation_rate=0.9)
    # no rate given: the floor stays at 0 and the update is the floor-less one
    none = Learner(cfg, 6, 2, 2).train_step(batch, snap)
    assert none["lambda2/floor"] == 0.0 and "lambda2/floor" not in off
    assert none["actor/loss"] == off["actor/loss"]
    learner = Learner(cfg, 6, 2, 2)
    first = learner.train_step(batch, snap, violation_rate=0.6)
    assert learner.lam2_floor == pytest.approx(0.05)
    assert first["lambda2/floor"] == pytest.approx(0.05)
    assert first["lambda2/real_rate"] == pytest.approx(0.6)
    # a floor above every λ2(s, z) (≈ 0.5 at initialisation): the actor weighs the cost with
    # it, λ2's own loss and estimate do not move
    high = Learner(cfg, 6, 2, 2)
    high.lam2_floor = 0.95  # a rate at the target leaves it there
    out = high.train_step(batch, snap, violation_rate=0.1)
    assert out["lambda2/actor_weight"] == pytest.approx(0.95)
    assert out["lambda2/mean"] == pytest.approx(off["lambda2/mean"])
    assert out["lambda2/loss"] == pytest.approx(off["lambda2/loss"])
    assert out["actor/loss"] != pytest.approx(off["actor/loss"])
    # the floor is part of the checkpoint
    high.save_checkpoint(tmp_path / "l.pt")
    again = Learner(cfg, 6, 2, 2)
    again.load_checkpoint(tmp_path / "l.pt")
    assert again.lam2_floor == pytest.approx(0.95)
    for bad in (
        {"lambda2_floor_lr": -1.0},
        {"lambda2_floor_target": 1.0},
        {"lambda2_floor_max": 1.5},
        {"lambda2_floor_window": 0},
    ):
        with pytest.raises(ValueError, match="lambda2_floor"):
            dataclasses.replace(MICRO, **bad)  # type: ignore[arg-type]


def test_serial_loop_feeds_the_rate_of_its_stored_steps() -> None:
    cfg = dataclasses.replace(
        MICRO,
        mode="ursa-supervised",
        train_ratio=2,
        lambda2_floor_lr=0.05,
        lambda2_floor_window=50,
    )
    sc = SerialConfig(prefill=50, skill_period=50, chunk_len=25, repertoire_size=200, n_z=20)
    loop = SerialLoop(PointEnv(seed=0), cfg, sc)
    loop.run(300)
    s = loop.replay._streams[loop.stream_id]
    unsafe = ~s.data["safe"][s.start : s.end]
    assert len(unsafe) == 300 and unsafe.any()
    ref = None  # chunk by chunk, as stored: the first chunk's mean starts the average
    for part in np.split(unsafe, 12):
        ref = ema_rate(ref, part, 50)
    assert loop.violation_rate == pytest.approx(ref)
    last = loop.history[-1]
    assert last["lambda2/real_rate"] == pytest.approx(loop.violation_rate, abs=0.2)
    assert loop.learner.lam2_floor > 0.0
