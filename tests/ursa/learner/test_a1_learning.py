"""A1 learning in CI (issue 20): the A1's CPU recipe (preset ``cpu``, URSA with the learned
feature function) trained in one process for ``ursa.config.TRAIN_STEPS["cpu"]`` env steps
(:data:`tests.trained.A1_RUN`, in the background beside the suite) acts safely: the violation
rate of its acting policy over its last :data:`WINDOW` env steps is below half that of uniformly
random actions on the same robot, which fall over and stay down (about 0.88).

The bar is the issue's: it fails when A1 learning breaks (an untrained or mistrained policy
falls as often as random actions do), not a claim about diverse skills.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.trained import A1_RUN, run_budget, run_config
from ursa.config import build_env
from ursa.rundir import RunDir

pytestmark = [pytest.mark.slow, pytest.mark.timeout(2400)]

WINDOW = 2000
"""Env steps at the end of the run over which its violation rate is taken (100 s of robot
time at 20 Hz, eight skills)."""
RANDOM_STEPS = 3000
"""Env steps of random actions that give the reference violation rate."""


def random_violation_rate(steps: int = RANDOM_STEPS, seed: int = 7) -> float:
    """Fraction of unsafe steps under uniformly random actions on the run's A1 (rescues on, as
    in training)."""
    env = build_env(run_config(A1_RUN), seed=seed)
    rng = np.random.default_rng(seed)
    try:
        unsafe = 0
        for _ in range(steps):
            *_, info = env.step(rng.uniform(-1.0, 1.0, env.act_dim))
            unsafe += 0 if info["safe"] else 1
    finally:
        env.close()
    return unsafe / steps


def final_violation_rate(run_dir: Path, window: int = WINDOW) -> tuple[float, int]:
    """(violation rate over the last ``window`` env steps, env steps) of a serial run, from
    its collector metrics (cumulative unsafe steps every 1000 env steps)."""
    rows = [
        json.loads(line)["scalars"]
        for line in (run_dir / "metrics" / "collector-serial.jsonl").read_text().splitlines()
    ]
    end = rows[-1]
    start = next(r for r in rows if r["steps"] >= end["steps"] - window)
    n = end["steps"] - start["steps"]
    return (end["unsafe_total"] - start["unsafe_total"]) / n, int(end["steps"])


def test_a1_cpu_recipe_becomes_safe(a1_cpu_run: Path) -> None:
    rate, steps = final_violation_rate(a1_cpu_run)
    _, budget = run_budget(A1_RUN)
    assert steps >= budget - 1000  # the run's whole budget was trained
    state = json.loads(RunDir(a1_cpu_run).learner_state.read_text())
    rand = random_violation_rate()
    print(
        f"\nA1 cpu recipe: violation rate {rate:.3f} over the last {WINDOW} of {steps} env "
        f"steps, {state['updates']} updates; random actions {rand:.3f}"
    )
    assert rand > 0.6  # random actions topple the robot: the comparison means something
    assert rate < 0.5 * rand
