"""One preset table: every entry point offers exactly the core's presets, and the point recipe
the learning tests train is the core's ``point`` preset (no recipe constant under tests/)."""

from __future__ import annotations

import dataclasses
import typing

from services.common.cli import PRESETS
from services.launcher import UpArgs
from tests import trained
from ursa.config import PREFILL, TRAIN_STEPS, PresetName, preset


def test_every_entry_point_offers_the_core_presets() -> None:
    core = typing.get_args(PresetName)
    assert core == PRESETS
    hints = typing.get_type_hints(UpArgs)
    assert typing.get_args(hints["preset"]) == core


def test_the_learning_tests_train_the_point_preset() -> None:
    cfg = preset("point", "point")
    for name, (mode, seed) in trained.RUNS.items():
        want = dataclasses.replace(
            cfg, learner=dataclasses.replace(cfg.learner, mode=mode, seed=seed)
        )
        assert trained.point_config(mode, seed) == want, name
    assert PREFILL["point"] == trained.PREFILL_STEPS
    assert TRAIN_STEPS["point"] == trained.ENV_STEPS
    # the recipe differs from tiny in rates and horizons, never in code paths or sizes
    tiny = preset("tiny", "point").learner
    assert (cfg.learner.deter, cfg.learner.units) == (tiny.deter, tiny.units)
    assert cfg.learner.delta_scale == 0.25 and cfg.learner.train_ratio == 128.0
