"""Issue 16: a short ``ursa up`` run leaves TensorBoard event files that TensorBoard's own reader
finds the learner's and the collectors' scalars in, at increasing steps (the learner's updates
and env steps, the collectors' env steps)."""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from services.stack import free_port, launch_up, stop_up, wait_for

pytestmark = pytest.mark.slow


def _steps(d: Path, tag: str) -> list[tuple[int, float]]:
    """(step, value) of one tag in a TensorBoard run directory ([] while it has none)."""
    if not d.is_dir():
        return []
    acc = EventAccumulator(str(d))
    acc.Reload()
    if tag not in acc.Tags()["scalars"]:
        return []
    return [(e.step, e.value) for e in acc.Scalars(tag)]


def _increasing(steps: list[tuple[int, float]], n: int) -> bool:
    """At least n distinct positive steps, never decreasing."""
    s = [st for st, _ in steps]
    return s == sorted(s) and len({x for x in s if x > 0}) >= n


def test_stack_writes_tensorboard_scalars_at_increasing_steps(tmp_path: Path) -> None:
    run_id = f"tb-{uuid.uuid4().hex[:8]}"
    runs = tmp_path / "runs"
    tb = runs / run_id / "tensorboard"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "URSA_METRICS_EVERY_S": "1"}
    launcher = launch_up(run_id, runs, free_port(), tmp_path / "launcher.log", env)
    try:

        def trained() -> bool:
            return (
                _increasing(_steps(tb / "learner-main", "wm/loss"), 3)
                and _increasing(_steps(tb / "learner-main.env_steps", "wm/loss"), 3)
                and all(
                    _increasing(_steps(tb / f"collector-{c}", "steps_per_s"), 3)
                    for c in ("c0", "c1")
                )
            )

        wait_for(trained, 240, "three learner and collector rows at growing steps", every=2.0)
    finally:
        stop_up(launcher, 30)
    out = (tmp_path / "launcher.log").read_text()
    assert f"--logdir {tb}" in out, out[-3000:]

    # the learner's step is its update count, the env-step run's its ingested steps: both are
    # the row's own scalars (same wall times in both runs)
    upd = _steps(tb / "learner-main", "updates")
    assert upd and all(step == int(v) for step, v in upd)
    env_steps = _steps(tb / "learner-main.env_steps", "ingested_steps")
    assert env_steps and all(step == int(v) for step, v in env_steps)
    assert len(upd) == len(env_steps)
    # a collector's step is its env step count, and its env steps grow between rows
    for c in ("c0", "c1"):
        st = _steps(tb / f"collector-{c}", "steps")
        assert all(step == int(v) for step, v in st) and _increasing(st, 3)
    # the repertoire's scalars are there too, at its commit count
    assert _steps(tb / "repertoire-main", "size")
