"""Replay: gap detection, FIFO eviction, sampling shapes, state round trip."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from ursa.replay import Replay


def _chunk(stream: int, first: int, n: int) -> dict[str, np.ndarray]:
    steps = np.arange(first, first + n)
    return {
        "obs": np.stack(
            [np.full(n, stream), steps, np.zeros(n), np.zeros(n), np.zeros(n), steps], 1
        ),
        "action": np.zeros((n, 2)),
        "reward": steps.astype(np.float32),
        "cost": -np.ones(n),
        "safe": np.ones(n, bool),
        "features": np.zeros((n, 2)),
        "skill": np.zeros((n, 3)),
    }


def _flags(rep: Replay, sid: str) -> np.ndarray:
    s = rep._streams[sid]
    return s.is_first[s.start : s.end].copy()


def test_gap_detection_per_stream() -> None:
    rep = Replay(1000)
    rep.add(0, _chunk(0, 0, 10), first_step=0)
    rep.add(0, _chunk(0, 10, 10), first_step=10)  # contiguous
    rep.add(1, _chunk(1, 0, 5), first_step=0)  # another collector
    rep.add(0, _chunk(0, 25, 5), first_step=25)  # lost chunk 20..24
    rep.add(0, _chunk(0, 0, 5), first_step=0)  # restarted collector
    assert len(rep) == 35 and rep.inserted == 35 and rep.gaps == 2
    f0 = _flags(rep, "0")
    assert np.flatnonzero(f0).tolist() == [0, 20, 25]
    assert np.flatnonzero(_flags(rep, "1")).tolist() == [0]


def test_sample_shapes_and_contiguity() -> None:
    rep = Replay(10_000)
    for s in range(3):
        for c in range(4):
            rep.add(s, _chunk(s, 50 * c, 50), first_step=50 * c)
    rng = np.random.default_rng(0)
    batch = rep.sample(16, 32, rng)
    assert batch["obs"].shape == (16, 32, 6)
    assert batch["action"].shape == (16, 32, 2)
    assert batch["reward"].shape == (16, 32) and batch["reward"].dtype == np.float32
    assert batch["skill"].shape == (16, 32, 3)
    assert batch["safe"].dtype == bool
    assert batch["is_first"].shape == (16, 32) and batch["is_first"][:, 0].all()
    assert not batch["is_first"][:, 1:].any()  # no gaps were inserted
    # one stream per sequence, consecutive steps
    assert np.all(batch["obs"][:, :, 0] == batch["obs"][:, :1, 0])
    assert np.all(np.diff(batch["obs"][:, :, 1], axis=1) == 1)


def test_sequences_cross_gaps_with_flag() -> None:
    rep = Replay(1000)
    rep.add("a", _chunk(0, 0, 4), 0)
    rep.add("a", _chunk(0, 100, 4), 100)  # gap
    batch = rep.sample(64, 8, np.random.default_rng(1))  # only one valid start
    assert np.flatnonzero(batch["is_first"][0]).tolist() == [0, 4]
    with pytest.raises(ValueError):
        rep.sample(1, 9, np.random.default_rng(1))


def test_fifo_eviction_across_streams() -> None:
    rep = Replay(30)
    rep.add(0, _chunk(0, 0, 20), 0)
    rep.add(1, _chunk(1, 0, 10), 0)
    rep.add(1, _chunk(1, 10, 10), 10)  # 40 > 30: the 10 oldest (stream 0, steps 0..9) go
    assert len(rep) == 30
    s0 = rep._streams["0"]
    assert s0.data["obs"][s0.start, 1] == 10
    rep.add(2, _chunk(2, 0, 15), 0)  # stream 0 (older) loses its last 10, stream 1 five
    assert len(rep) == 30
    assert len(rep._streams["0"]) == 0
    s1 = rep._streams["1"]
    assert s1.data["obs"][s1.start, 1] == 5
    assert rep.inserted == 55


def test_state_dict_round_trip(tmp_path: object) -> None:
    rep = Replay(500)
    for c in range(6):
        rep.add("x", _chunk(0, 40 * c + (5 if c == 3 else 0), 40), 40 * c + (5 if c == 3 else 0))
        rep.add("y", _chunk(1, 40 * c, 40), 40 * c)
    state = rep.state_dict()
    assert all(isinstance(v, np.ndarray) for v in state.values())
    path = f"{tmp_path}/replay.npz"
    arrays: dict[str, Any] = dict(state)
    np.savez(path, **arrays)
    with np.load(path, allow_pickle=False) as data:
        back = Replay.from_state_dict({k: data[k] for k in data.files})
    assert len(back) == len(rep) and back.gaps == rep.gaps and back.inserted == rep.inserted
    a = rep.sample(8, 16, np.random.default_rng(5))
    b = back.sample(8, 16, np.random.default_rng(5))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    # both continue identically (next expected step and eviction order survive)
    rep.add("x", _chunk(0, 245, 30), 245)
    back.add("x", _chunk(0, 245, 30), 245)
    assert rep.gaps == back.gaps
    for k, v in rep.state_dict().items():
        np.testing.assert_array_equal(v, back.state_dict()[k])


def test_rejects_inconsistent_chunks() -> None:
    rep = Replay(100)
    rep.add(0, _chunk(0, 0, 5), 0)
    bad = _chunk(0, 5, 5)
    bad["obs"] = bad["obs"][:, :4]
    with pytest.raises(ValueError):
        rep.add(0, bad, 5)
    missing = _chunk(0, 5, 5)
    del missing["skill"]
    with pytest.raises(ValueError):
        rep.add(0, missing, 5)
    ragged = _chunk(0, 5, 5)
    ragged["reward"] = ragged["reward"][:3]
    with pytest.raises(ValueError):
        rep.add(0, ragged, 5)


def _with_unsafe(stream: int, first: int, n: int, unsafe: list[int]) -> dict[str, np.ndarray]:
    c = _chunk(stream, first, n)
    c["safe"][unsafe] = False
    c["cost"][unsafe] = 1.0
    return c


def test_unsafe_fraction_puts_an_unsafe_step_in_that_many_sequences() -> None:
    rep = Replay(10_000)
    rep.add(0, _with_unsafe(0, 0, 500, [7, 300]), first_step=0)  # 2 of 1000 records unsafe
    rep.add(1, _chunk(1, 0, 500), first_step=0)
    rng = np.random.default_rng(0)
    held, hits = [], {7: 0, 300: 0}
    for _ in range(200):
        b = rep.sample(16, 20, rng, unsafe_fraction=0.25)
        unsafe = ~b["safe"]
        held.append(unsafe.any(1))
        # the drawn windows: contiguous steps of stream 0 that contain step 7 or 300
        for row in range(4):
            assert b["obs"][row, 0, 0] == 0
            steps = b["obs"][row, :, 1]
            assert np.array_equal(steps, steps[0] + np.arange(20))
            for i in hits:
                hits[i] += int(i in steps)
    frac = np.stack(held)  # (200, 16)
    assert frac[:, :4].all()  # the first round(0.25 · 16) hold an unsafe step, always
    assert frac[:, 4:].mean() < 0.1  # uniform windows: ~39 of 962 hold one
    # both unsafe records drawn, near-equally (7's windows are clipped at the stream's start)
    assert 300 < hits[7] < 500 and 300 < hits[300] < 500
    # without the option the draws are the plain uniform ones, rng use unchanged
    a = rep.sample(16, 20, np.random.default_rng(1))
    z = rep.sample(16, 20, np.random.default_rng(1), unsafe_fraction=0.0)
    assert all(np.array_equal(a[k], z[k]) for k in a)


def test_unsafe_fraction_without_unsafe_records_is_uniform() -> None:
    rep = Replay(1000)
    rep.add(0, _chunk(0, 0, 100), first_step=0)
    rep.add(1, _with_unsafe(1, 0, 10, [3]), first_step=0)  # shorter than a sequence
    b = rep.sample(8, 20, np.random.default_rng(0), unsafe_fraction=1.0)
    assert b["safe"].all() and (b["obs"][:, 0, 0] == 0).all()
    with pytest.raises(ValueError, match="unsafe_fraction"):
        rep.sample(8, 20, np.random.default_rng(0), unsafe_fraction=1.5)
