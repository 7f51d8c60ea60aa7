"""The declared boxes hold everything the envs produce, and the repertoire never admits a skill
outside them (repairing an archive on load)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ursa import bounds
from ursa.bounds import Box, OutOfBounds
from ursa.config import build_env, preset
from ursa.repertoire import Repertoire, RepertoireConfig


def test_check_names_the_first_offending_value() -> None:
    box = Box((-1.0, 0.0), (1.0, 2.0))
    x = np.array([[0.0, 1.0], [0.5, 2.5], [np.nan, 1.0]])
    with pytest.raises(OutOfBounds, match=r"skill\[1\]\[1\] = 2.5 outside \[0, 2\]"):
        bounds.check("skill", x, box)
    np.testing.assert_array_equal(box.contains(x), [True, False, False])
    assert bounds.check("skill", x[:1], box).dtype == np.float64
    with pytest.raises(OutOfBounds, match="width"):
        bounds.check("skill", np.zeros((2, 3)), box)
    with pytest.raises(OutOfBounds, match="not finite"):
        bounds.check_finite("w", np.array([1.0, np.inf]), 10.0)
    with pytest.raises(OutOfBounds, match="within"):
        bounds.check_finite("w", np.array([1.0, 11.0]), 10.0)
    with pytest.raises(ValueError):
        Box((0.0,), (np.inf,))


def test_widened_box_grows_by_its_width() -> None:
    w = Box((-1.0, 0.0), (1.0, 1.0)).widened(1.0)
    assert w.low == (-3.0, -1.0) and w.high == (3.0, 2.0)


def _rollout_within(env_name: str, feature: str, steps: int) -> None:
    cfg = preset("tiny", env_name, feature)  # type: ignore[arg-type]
    d = bounds.declared(cfg)
    env = build_env(cfg, seed=3)
    obs, _ = env.reset()
    rng = np.random.default_rng(0)
    for t in range(steps):
        # full-scale random actions, NaNs and out-of-range commands included
        a = rng.uniform(-3.0, 3.0, size=env.act_dim)
        if t % 17 == 0:
            a[0] = np.nan
        obs, _, _, _, info = env.step(a)
        bounds.check("obs", obs, d.obs)
        bounds.check("prev_action", obs[-env.act_dim :], d.action)
        for name, box in d.feature_dims.items():
            bounds.check(name, info["features"][name], box)
        bounds.check("features", info["features"][cfg.feature_input_key], d.features)
    env.close()


def test_point_env_stays_inside_its_declared_boxes() -> None:
    _rollout_within("point", "position", 3000)


def test_a1_stays_inside_its_declared_boxes() -> None:
    _rollout_within("a1", "vae", 400)


def test_skill_boxes_follow_the_feature_function() -> None:
    point = bounds.declared(preset("tiny", "point"))
    assert point.skills == Box((-1.0, -1.0), (1.0, 1.0))
    assert point.samples == Box((-3.0, -3.0), (3.0, 3.0))
    a1 = bounds.declared(preset("tiny", "a1"))
    assert a1.skills.dim == 3 and a1.skills.high == (bounds.LATENT_BOUND,) * 3
    assert a1.features.dim == 13 and a1.obs.dim == 46
    assert bounds.declared(preset("tiny", "a1", "contacts")).skills == Box.uniform(4, 0.0, 1.0)


BOX = Box((-1.0, -1.0), (1.0, 1.0))


def test_repertoire_never_admits_out_of_bounds_or_non_finite_skills() -> None:
    rep = Repertoire(RepertoireConfig(size=20, dim=2), bounds=BOX)
    rng = np.random.default_rng(1)
    good = rng.uniform(-1, 1, (30, 2))
    bad = np.array([[4e30, 0.0], [0.0, -1.0001], [np.nan, 0.0], [np.inf, 0.5]])
    batch = np.concatenate([good[:10], bad, good[10:]])
    rep.commit_many(batch)
    assert rep.rejected_invalid == 4 and rep.rejected_out_of_bounds == 2
    assert rep.commits == 30 and len(rep) == 20
    assert BOX.contains(rep.skills).all()
    assert not rep.commit(np.array([2.0, 0.0]))
    assert rep.rejected_out_of_bounds == 3
    with pytest.raises(ValueError, match="dimension"):
        Repertoire(RepertoireConfig(size=5, dim=3), bounds=BOX)


def test_reencode_drops_skills_outside_the_box() -> None:
    rep = Repertoire(RepertoireConfig(size=10, dim=2, input_dim=3), bounds=BOX)
    x = np.random.default_rng(2).uniform(-1, 1, (8, 3))
    rep.commit_many(x[:, :2], x)
    dropped = rep.reencode(lambda v: v[:, :2] * np.array([1.0, 1e30]) ** (v[:, 2:3] > 0.5), 1)
    assert dropped == int((x[:, 2] > 0.5).sum()) > 0
    assert BOX.contains(rep.skills).all()


@pytest.mark.parametrize("full", [False, True], ids=["filling", "full"])
def test_an_archive_with_bad_skills_is_repaired_on_load(tmp_path: Path, full: bool) -> None:
    size = 12
    rep = Repertoire(RepertoireConfig(size=size, dim=2))  # written without bounds
    rng = np.random.default_rng(3)
    n = size if full else 9
    z = rng.uniform(-1, 1, (n, 2))
    z[2] = [5e30, 0.0]
    z[5] = [0.3, -7.0]
    rep.commit_many(z)
    path = tmp_path / "archive.npz"
    rep.save(path)
    state = dict(np.load(path))
    state["skills"][7] = [np.nan, 0.0]  # corrupted on disk
    np.savez(path, **state)

    back = Repertoire.load(path, bounds=BOX)
    assert back.repaired == 3 and len(back) == n - 3
    assert BOX.contains(back.skills).all()
    kept = np.delete(np.arange(n), [2, 5, 7])
    np.testing.assert_array_equal(back.ids, rep.ids[kept])
    np.testing.assert_allclose(back.skills, z[kept])
    # Σ and nearest neighbours follow the repaired archive, as a fresh one holding the same skills
    fresh = Repertoire(RepertoireConfig(size=size, dim=2), bounds=BOX)
    fresh.commit_many(z[kept])
    np.testing.assert_allclose(back.cov, fresh.cov)
    np.testing.assert_allclose(back.nn_dist, fresh.nn_dist)
    # the repaired archive accepts new skills and saves/loads again with nothing to repair
    back.commit_many(rng.uniform(-1, 1, (5, 2)))
    back.save(path)
    again = Repertoire.load(path, bounds=BOX)
    assert again.repaired == 0 and len(again) == len(back)
    assert Repertoire.load(path).repaired == 0  # without bounds only finiteness is checked
