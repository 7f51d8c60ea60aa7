"""The evaluation's pure parts: grid coverage, farthest-point sampling, config round trips,
metrics curves, PCA. Fast and exact (hand-worked values)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from ursa.config import Config, preset
from ursa.eval.common import jsonable
from ursa.eval.coverage import GridSpec, coverage, coverage_grid, coverage_specs, covered_cells
from ursa.eval.curves import compute_curves, cumulative, windowed_rate
from ursa.eval.embedding import embed_2d, pca_2d
from ursa.eval.loading import from_plain, load_config, to_plain
from ursa.eval.rollout import farthest_point_sampling
from ursa.eval.velocity import serpentine, target_grid
from ursa.learner_config import LearnerConfig


def test_coverage_grid_counts_cells_by_hand() -> None:
    pts = np.array([[0.0, 0.0], [0.1, 0.1], [0.99, 0.5], [1.0, 1.0], [1.5, 0.0], [np.nan, 0.0]])
    counts, outside = coverage_grid(pts, np.array([0.0, 0.0]), np.array([1.0, 1.0]), 4)
    assert counts.shape == (4, 4) and outside == 2
    assert counts[0, 0] == 2  # [0, 0.25)² holds two points
    assert counts[3, 2] == 1  # x 0.99 -> last column, y 0.5 -> cell 2 (half-open)
    assert counts[3, 3] == 1  # the upper edge belongs to the last cell
    assert counts.sum() == 4 and covered_cells(counts) == 3


def test_coverage_grid_one_dimension_and_bad_input() -> None:
    counts, outside = coverage_grid(
        np.array([[-1.0], [-0.5], [0.49], [0.5]]), np.array([-1.0]), np.array([1.0]), 4
    )
    np.testing.assert_array_equal(counts, [1, 1, 1, 1])  # cells [-1, -.5) [-.5, 0) [0, .5) [.5, 1]
    assert outside == 0
    with pytest.raises(ValueError):
        coverage_grid(np.zeros((3, 2)), np.zeros(1), np.ones(1), 4)
    with pytest.raises(ValueError):
        coverage_grid(np.zeros((3, 1)), np.ones(1), np.ones(1), 4)


def test_coverage_specs_a1_and_point() -> None:
    key, specs = coverage_specs(preset("tiny", "a1"), 10)
    assert key == "vae_input" and len(specs) == 12
    assert [s.name for s in specs[:3]] == ["FR hip", "FR upper", "FR lower"]
    assert specs[4].dims == (4,) and specs[4].low == (-1.0,) and specs[4].high == (2.8,)
    # the 12 joints at the standing pose cover one cell each
    stand = np.tile([0.0, 0.9, -1.8], 4)[None]
    cov = coverage(np.concatenate([stand, [[1.0]]], 1), specs)
    assert cov.covered == 12 and cov.total == 120
    key, specs = coverage_specs(preset("tiny", "point"), 20)
    assert key == "position" and len(specs) == 1 and specs[0].cells == 400
    cov = coverage(np.array([[0.0, 0.0], [0.01, 0.01], [-0.99, 0.99]]), specs)
    assert cov.covered == 2 and cov.per_grid() == {"position": 2}


def test_coverage_of_generic_spec() -> None:
    spec = GridSpec("ab", (1, 2), (0.0, 0.0), (1.0, 2.0), (2, 4))
    cov = coverage(np.array([[9.0, 0.2, 1.9], [9.0, 0.7, 0.1]]), [spec])
    assert cov.counts[0].shape == (2, 4) and cov.counts[0][0, 3] == 1 and cov.counts[0][1, 0] == 1


def test_farthest_point_sampling_by_hand() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [0.0, 3.0], [5.0, 0.1]])
    idx = farthest_point_sampling(pts, 3, start=0)
    # from 0: farthest is 2 (10); then min distances: 1->1, 3->3, 4->~5 -> 4
    np.testing.assert_array_equal(idx, [0, 2, 4])
    # default start: farthest from the mean (3.2, 0.62) is point 2
    assert farthest_point_sampling(pts, 1)[0] == 2
    # Mahalanobis: stretching y by 100 (cov diag 1, 1e-4) makes point 3 the farthest from 0
    idx = farthest_point_sampling(pts, 2, cov=np.diag([1.0, 1e-4]), start=0)
    np.testing.assert_array_equal(idx, [0, 3])
    assert len(farthest_point_sampling(pts, 99)) == 5
    assert len(set(farthest_point_sampling(pts, 5).tolist())) == 5
    assert len(farthest_point_sampling(pts, 0)) == 0


def test_config_round_trip_through_yaml(tmp_path: Path) -> None:
    cfg = preset("tiny", "a1", "velocity")
    cfg = dataclasses.replace(
        cfg,
        a1=dataclasses.replace(cfg.a1, damage="front_upper", kp=(90.0, 91.0, 92.0)),
        learner=dataclasses.replace(cfg.learner, mode="ursa-supervised", seed=3),
    )
    doc = {
        "argv": ["--core.feature", "velocity"],
        "config": {"core": to_plain(cfg), "bus": {"router": "tcp/x:1"}},
    }
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "learner.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    got = load_config(tmp_path)
    assert got == cfg
    assert isinstance(got.a1.kp, tuple) and isinstance(got.point.goal, tuple)
    assert got.skill_dim == 2 and got.feature == "velocity"


def test_from_plain_types_defaults_and_unknown_keys() -> None:
    lc = from_plain(LearnerConfig, {"mode": "daydreamer", "discount": 1 - 1e-3, "units": 32.0})
    assert lc.mode == "daydreamer" and lc.units == 32 and isinstance(lc.units, int)
    assert lc.deter == LearnerConfig().deter  # missing -> default
    with pytest.warns(UserWarning, match="unknown"):
        cfg = from_plain(Config, {"env": "point", "future_field": 1, "point": {"goal": [0.1, 0.2]}})
    assert cfg.point.goal == (0.1, 0.2) and cfg.env == "point"
    with pytest.raises(ValueError):
        from_plain(Config, {"env": "mars"})
    with pytest.raises(TypeError):
        from_plain(LearnerConfig, {"units": "many"})
    assert from_plain(Config, {"a1": {"damage": None}}).a1.damage is None


def test_cumulative_counter_survives_restarts() -> None:
    np.testing.assert_array_equal(cumulative(np.array([0, 5, 10, 2, 4, 1])), [0, 5, 10, 12, 14, 15])


def test_windowed_rate_by_hand() -> None:
    den = np.array([0.0, 10.0, 20.0, 20.0, 40.0, 50.0])
    num = np.array([0.0, 1.0, 1.0, 1.0, 5.0, 5.0])
    # window 1: from the latest point at least 1 step back (point 3 skips its twin, point 2)
    idx, rate = windowed_rate(num, den, 1.0)
    np.testing.assert_array_equal(idx, [1, 2, 3, 4, 5])
    np.testing.assert_allclose(rate, [0.1, 0.0, 0.0, 0.2, 0.0])
    # window 20: point 1 has nothing that far back and uses point 0
    idx, rate = windowed_rate(num, den, 20.0)
    np.testing.assert_allclose(rate, [0.1, 0.05, 0.05, 0.2, 4.0 / 30.0])
    idx, _ = windowed_rate(np.zeros(3), np.zeros(3), 1.0)  # no progress: no rate
    assert len(idx) == 0


def _write_metrics(run: Path) -> None:
    rows = []
    # two collectors, 1000 steps per 10 s each; the second restarts its counters at t = 30
    for k in range(7):
        t = 10.0 * k
        rows.append(
            {
                "t": t,
                "service": "collector",
                "id": "0",
                "scalars": {
                    "steps": 1000 * k,
                    "unsafe_total": 100 * k,
                    "rescues": k,
                    "return_mean": 2.0,
                    "violation_rate": 0.1,
                },
            }
        )
        s = 1000 * k if k <= 3 else 1000 * (k - 4)
        rows.append(
            {
                "t": t + 0.5,
                "service": "collector",
                "id": "1",
                "scalars": {
                    "steps": s,
                    "unsafe_total": 0,
                    "rescues": 0,
                    "return_mean": 4.0,
                    "violation_rate": 0.0,
                },
            }
        )
        rows.append(
            {
                "t": t + 1.0,
                "service": "repertoire",
                "id": "main",
                "scalars": {"size": 10 * k, "delta": 0.5, "entropy_bound": -1.0 + k},
            }
        )
    (run / "metrics").mkdir(parents=True)
    text = "\n".join(json.dumps(r) for r in rows) + "\n{partial line"
    (run / "metrics" / "all-0.jsonl").write_text(text)


def test_curves_from_metrics(tmp_path: Path) -> None:
    _write_metrics(tmp_path)
    c = compute_curves(tmp_path, control_hz=20.0)
    steps = c["return"]["steps"]
    # collector 1 restarted: 3000 steps, then 0..2000 on top
    assert np.all(np.diff(steps) >= 0) and steps[-1] == 6000 + 5000
    # collector 0 is unsafe 10% of its steps, collector 1 never: about 5% overall
    v = c["violation_rate"]["value"]
    assert np.all((v >= 0) & (v <= 1)) and np.median(v) == pytest.approx(0.05, abs=0.01)
    # 1 rescue per 1000 steps of collector 0 = per 50 s of robot time at 20 Hz, over two robots
    r = c["rescues_per_hour"]["value"]
    assert np.median(r) == pytest.approx(3600 / 100, rel=0.1)
    np.testing.assert_allclose(c["return"]["value"], 3.0)
    assert c["repertoire_size"]["value"][-1] == 60 and c["entropy_bound"]["value"][-1] == 5.0


def test_pca_and_embedding() -> None:
    rng = np.random.default_rng(0)
    x = np.zeros((200, 5))
    x[:, 0] = rng.normal(0, 10, 200)
    x[:, 3] = rng.normal(0, 1, 200)
    e = pca_2d(x)
    assert e.method == "pca" and e.points.shape == (200, 2)
    assert e.explained[0] > 0.95 and abs(sum(e.explained) - 1.0) < 1e-9
    assert abs(np.corrcoef(e.points[:, 0], x[:, 0])[0, 1]) > 0.999  # the big axis comes first
    assert e.points[:, 0].var() == pytest.approx(x[:, 0].var() + 0.0, rel=0.02)
    e2 = embed_2d(x, "pca")
    assert e2.points.shape == (200, 2) and e2.explained[0] == pytest.approx(0.5, abs=0.1)
    assert embed_2d(x, "auto").method in ("pca", "umap")


def test_target_grid_and_serpentine() -> None:
    axes = target_grid(np.array([[0.0, -1.0], [1.0, 1.0], [0.5, 0.0]]), 3, margin=0.5)
    np.testing.assert_allclose(axes[0], [-0.5, 0.5, 1.5])
    np.testing.assert_allclose(axes[1], [-2.0, 0.0, 2.0])
    pts = np.concatenate([np.linspace(0, 1, 101)[:, None].repeat(2, 1), [[50.0, -50.0]]])
    q = target_grid(pts, 2, quantile=0.05)  # the outlier no longer stretches the box
    assert q[0][-1] < 1.0 and q[1][0] > -1.0
    flat = target_grid(np.ones((4, 2)), 2)
    assert flat[0][1] > flat[0][0]
    order = serpentine(2, 3)
    assert order == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 1), (1, 0)]


def test_jsonable_handles_numpy_and_nan() -> None:
    got = jsonable({"a": np.float32(1.5), "b": np.arange(2), "c": float("nan"), 3: (np.int64(2),)})
    assert json.loads(json.dumps(got)) == {"a": 1.5, "b": [0, 1], "c": None, "3": [2]}


def test_damage_runs_must_share_the_task_and_reward() -> None:
    from types import SimpleNamespace

    from ursa.eval.damage import check_same_task

    def run(name: str, **a1: Any) -> Any:
        cfg = preset("small", "a1")
        return SimpleNamespace(
            name=name, config=dataclasses.replace(cfg, a1=dataclasses.replace(cfg.a1, **a1))
        )

    # what an evaluation sets itself may differ; the task, reward and control may not
    check_same_task([run("u"), run("d", rescue=False, damage="front_hip", frozen_joints=(4,))])
    with pytest.raises(ValueError, match="task"):
        check_same_task([run("u"), run("d", task="posture")])
    with pytest.raises(ValueError, match="target_speed"):
        check_same_task([run("u"), run("v"), run("d", target_speed=0.5)])
