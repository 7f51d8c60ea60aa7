"""One preset table: every entry point offers exactly the core's presets, and the point recipe
the learning tests train is the core's ``point`` preset (no recipe constant under tests/)."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

import pytest

from services.common.cli import PRESETS
from services.launcher import UpArgs
from tests import trained
from ursa.config import PREFILL, TRAIN_STEPS, PresetName, preset


def test_every_entry_point_offers_the_core_presets() -> None:
    core = typing.get_args(PresetName)
    assert core == PRESETS
    hints = typing.get_type_hints(UpArgs)
    assert typing.get_args(hints["preset"]) == ("auto", *core)  # auto picks one of them


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
    # the A1 run of the CPU recipe is the core's cpu preset, with its budget
    assert trained.run_config(trained.A1_RUN) == preset("cpu", "a1")
    assert trained.run_budget(trained.A1_RUN) == (PREFILL["cpu"], TRAIN_STEPS["cpu"])


def test_environment_defaults_are_read_when_the_config_is_made(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Host, port, ids and endpoints default to their environment variables as they are when
    a config is made, not when its module was first imported (a test or a launcher that sets
    them later is obeyed)."""
    from services.api.service import ApiArgs
    from services.common.config import BusConfig, RunConfig
    from services.learner.service import LearnerArgs

    monkeypatch.setenv("URSA_ROUTER", "tcp/10.1.2.3:7447")
    monkeypatch.setenv("URSA_RUNS_DIR", "/tmp/somewhere")
    monkeypatch.setenv("URSA_WANDB", "offline")
    monkeypatch.setenv("URSA_API_PORT", "8123")
    monkeypatch.setenv("URSA_TORCH_THREADS", "3")
    assert BusConfig().router == "tcp/10.1.2.3:7447"
    assert RunConfig().root == Path("/tmp/somewhere") and RunConfig().wandb == "offline"
    assert ApiArgs().port == 8123 and ApiArgs().bus.router == "tcp/10.1.2.3:7447"
    assert LearnerArgs().torch_threads == 3
    monkeypatch.setenv("URSA_WANDB", "bogus")
    assert RunConfig().wandb == "off"


@pytest.mark.parametrize("flag", ["--feature", "--core.feature"])
def test_either_feature_flag_sets_the_dimensions_that_follow_from_it(flag: str) -> None:
    """``--core.feature velocity`` (the field's own flag) used to change only the name: the
    repertoire kept the learned feature's 3 dimensions against the velocity's 2 bounds and
    crashed, and the learner dropped every chunk. Both spellings pick the feature."""
    from services.common.cli import parse
    from services.learner.service import LearnerArgs

    args = parse(LearnerArgs, ["--preset", "cpu", "--env", "a1", flag, "velocity"])
    assert args.core == preset("cpu", "a1", "velocity")
    assert args.core.feature == "velocity" and args.core.repertoire.dim == 2
    assert preset("cpu", "a1").repertoire.dim == 3  # what the old parse left in place
    args = parse(LearnerArgs, ["--preset", "cpu", f"{flag}=velocity", "--core.learner.seed", "4"])
    assert args.core.repertoire.dim == 2 and args.core.learner.seed == 4
