"""The core config alone is a valid config, and every preset's dimensions agree."""

from __future__ import annotations

import typing

import pytest

from ursa.config import PROVIDED_FEATURES, VAE_INPUT_DIM, Config, PresetName, preset


def test_the_default_config_is_the_small_preset() -> None:
    cfg = Config()
    assert cfg == preset("small")
    assert cfg.feature == "vae" and cfg.repertoire.input_dim == VAE_INPUT_DIM["a1"]
    assert cfg.repertoire.dim == cfg.learner.skill_dim == 3 and cfg.learner.mode == "ursa"


@pytest.mark.parametrize("name", typing.get_args(PresetName))
def test_every_preset_env_and_feature_is_consistent(name: PresetName) -> None:
    for env, feats in PROVIDED_FEATURES.items():
        for feature in [*feats, *(["vae"] if env in VAE_INPUT_DIM else [])]:
            cfg = preset(name, env, feature)  # type: ignore[arg-type]
            assert cfg.preset == name and cfg.env == env and cfg.feature == feature
            assert cfg.learner.skill_dim == cfg.repertoire.dim == cfg.skill_dim
            if feature == "vae":
                assert cfg.repertoire.input_dim == VAE_INPUT_DIM[env]
                assert cfg.learner.mode == "ursa"
            else:
                assert cfg.repertoire.dim == feats[feature] and cfg.repertoire.input_dim is None
                assert cfg.learner.mode == "ursa-supervised"
    with pytest.raises(ValueError, match="learned feature"):
        preset(name, "point", "vae")
