"""scripts/a1_stack_curve.py: a stack run's pooled violation windows, worked by hand."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from pathlib import Path
from typing import Any

_spec = importlib.util.spec_from_file_location(
    "a1_stack_curve", Path(__file__).resolve().parents[2] / "scripts" / "a1_stack_curve.py"
)
assert _spec is not None and _spec.loader is not None
sc = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sc)


def _c(t: float, steps: float, unsafe: float) -> dict[str, Any]:
    return {"t": t, "scalars": {"steps": steps, "unsafe_total": unsafe}}


def _l(t: float, updates: int, lam2: float) -> dict[str, Any]:
    return {"t": t, "scalars": {"updates": updates, "lambda2/mean": lam2}}


def test_windows_pool_the_collectors_and_average_the_learner() -> None:
    c0 = [_c(0, 0, 0), _c(10, 400, 100), _c(20, 800, 100), _c(30, 1200, 110)]
    c1 = [_c(5, 300, 0), _c(15, 600, 300), _c(25, 900, 300)]  # seen from t = 5
    learner = [_l(12, 10, 0.5), _l(18, 20, 0.7), _l(28, 30, 0.9)]
    rows = sc.curve([c0, c1], learner, window=1000)
    # pooled (t, steps, unsafe): (0,0,0) (5,300,0) (10,700,100) (15,1000,400) (20,1400,400)
    # (25,1700,400) (30,2100,410): windows close at t = 15 (1000 steps) and 30 (1100 more)
    assert [r["t"] for r in rows] == [15, 30]
    assert [r["env_steps"] for r in rows] == [1000, 2100]
    assert rows[0]["violation_rate"] == 400 / 1000
    assert math.isclose(rows[1]["violation_rate"], 10 / 1100)
    assert rows[0]["updates"] == 10 and rows[1]["updates"] == 30
    assert rows[0]["lambda2"] == 0.5 and math.isclose(rows[1]["lambda2"], 0.8)
    assert math.isnan(rows[0]["entropy"])  # not in the learner's rows


def test_overrides_are_the_fields_that_differ() -> None:
    from ursa.config import preset

    base = preset("cpu", "a1", "velocity").learner
    cfg = dataclasses.replace(base, lambda2_floor_max=0.75, seed=3)
    assert sc.overrides(cfg, base) == {"lambda2_floor_max": 0.75, "seed": 3}
