"""Every ``ursa eval`` command on small checkpoints: point env (fast) and short A1 runs (slow).
Checks that the files exist and hold values in their valid ranges."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.ursa.eval._runs import small_config
from ursa.eval.cli import main
from ursa.eval.loading import load_run
from ursa.repertoire import Repertoire

pytestmark = pytest.mark.timeout(600)

QUIET = ["--no-progress"]


def _json(path: Path) -> dict[str, Any]:
    assert path.is_file(), path
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def _csv(path: Path) -> list[dict[str, str]]:
    assert path.is_file(), path
    with open(path) as f:
        return list(csv.DictReader(f))


def _png(path: Path) -> None:
    assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", path
    assert path.stat().st_size > 5000


@pytest.fixture(scope="module")
def point_run(run_factory: Callable[..., Path]) -> Path:
    return run_factory("point-ursa", small_config("point"), steps=400, prefill=200)


@pytest.fixture(scope="module")
def point_dd(run_factory: Callable[..., Path]) -> Path:
    return run_factory("point-dd", small_config("point", mode="daydreamer"), steps=300, prefill=200)


def test_run_dir_round_trip(point_run: Path) -> None:
    run = load_run(point_run)
    assert run.config == small_config("point")
    assert run.policy is not None and run.updates > 0 and run.policy.version == run.updates
    assert run.repertoire is not None and len(run.repertoire) > 1
    assert run.dims == (6, 2, 2, 2)
    # the checkpoint path alone finds its run directory
    again = load_run(point_run / "checkpoints" / "learner.pt")
    assert again.run_dir == point_run and again.config == run.config
    assert isinstance(Repertoire.load(point_run / "repertoire" / "archive.npz"), Repertoire)
    state = json.loads((point_run / "checkpoints" / "learner_state.json").read_text())
    assert state["updates"] == run.updates


def test_bare_checkpoint_loads(point_run: Path, tmp_path: Path) -> None:
    bare = tmp_path / "x.pt"
    bare.write_bytes((point_run / "checkpoints" / "learner.pt").read_bytes())
    run = load_run(bare)
    assert run.run_dir is None and run.config.env == "point" and run.config.feature == "position"
    assert run.config.learner == small_config("point").learner and run.repertoire is None


def test_diversity_point(point_run: Path, point_dd: Path, tmp_path: Path) -> None:
    out = tmp_path / "div"
    argv = ["diversity", str(point_run), "--baseline", str(point_dd), "--out", str(out),
            "--skills", "12", "--steps", "30", "--bins", "10", *QUIET]
    assert main(argv) == 0
    s = _json(out / "diversity.json")
    _png(out / "diversity.png")
    assert s["env"] == "point" and s["feature_key"] == "position"
    for label in ("ursa", "baseline"):
        r = s["runs"][label]
        assert 1 <= r["covered_cells"] <= r["total_cells"] == 100
        assert r["executions"] == 12 and math.isfinite(r["return_mean"])
        assert 0.0 <= r["violation_rate_mean"] <= 1.0
    assert s["runs"]["baseline"]["mode"] == "daydreamer"
    assert 0.0 <= s["runs"]["ursa"]["within_delta_fraction"] <= 1.0
    assert s["ratio"] == s["runs"]["ursa"]["covered_cells"] / s["runs"]["baseline"]["covered_cells"]
    rows = _csv(out / "diversity_means.csv")
    assert len(rows) == 24
    means = np.array([[float(r["mean_position_0"]), float(r["mean_position_1"])] for r in rows])
    assert np.all(np.abs(means) <= 1.0)  # the arena
    cells = _csv(out / "diversity_cells_ursa.csv")
    assert sum(int(c["count"]) > 0 for c in cells) == s["runs"]["ursa"]["covered_cells"]


def test_default_out_is_run_eval(point_run: Path) -> None:
    assert main(["embedding", str(point_run), "--skills", "3", "--steps", "15", *QUIET]) == 0
    s = _json(point_run / "eval" / "embedding.json")
    _png(point_run / "eval" / "embedding.png")
    assert s["method"] == "pca" and s["skills"] == 3 and s["steps"] == 15
    assert 0.0 <= sum(s["explained_variance"]) <= 1.0 + 1e-9
    rows = _csv(point_run / "eval" / "embedding.csv")
    assert len(rows) == 45 and all(math.isfinite(float(r["x"])) for r in rows)


def test_velocity_on_point_positions(point_run: Path, tmp_path: Path) -> None:
    # the point env's provided φ (position) is 2-D: the tracking evaluation applies as is
    out = tmp_path / "vel"
    assert main(["velocity", str(point_run), "--out", str(out), "--grid", "3", "--steps", "20",
                 *QUIET]) == 0
    s = _json(out / "velocity.json")
    _png(out / "velocity.png")
    err = np.array(s["error"])
    assert err.shape == (3, 3, 2) and np.all(err >= 0) and np.all(np.isfinite(err))
    assert np.all(np.array(s["step_error_mean"]) >= 0)
    rep = load_run(point_run).require_repertoire().skills
    np.testing.assert_allclose([s["axes"][0][0], s["axes"][0][-1]],
                               [rep[:, 0].min(), rep[:, 0].max()])
    assert len(_csv(out / "velocity.csv")) == 9


def test_curves_point(point_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "curves"
    assert main(["curves", str(point_run), "--out", str(out), *QUIET]) == 0
    s = _json(out / "curves.json")
    _png(out / "curves.png")
    assert s["env_steps"] == 400
    f = s["final"]
    assert 0.0 <= f["violation_rate"] <= 1.0 and f["rescues_per_hour"] == 0.0
    assert 1 < f["repertoire_size"] <= 300 and f["delta"] > 0 and math.isfinite(f["entropy_bound"])
    assert math.isfinite(f["return"])
    curves = {r["curve"] for r in _csv(out / "curves.csv")}
    assert {"violation_rate", "rescues_per_hour", "return", "repertoire_size", "delta",
            "entropy_bound"} <= curves


def test_all_runs_what_applies(point_run: Path, point_dd: Path, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "all"
    assert main(["all", str(point_run), "--baseline", str(point_dd), "--out", str(out),
                 "--skills", "4", "--steps", "10", *QUIET]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["ran"] == ["curves", "embedding", "diversity", "velocity"]  # no A1: no damage
    for name in ("curves", "embedding", "diversity", "velocity"):
        _png(out / f"{name}.png")
        _json(out / f"{name}.json")


def test_errors_are_reported(point_run: Path, point_dd: Path, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["damage", str(point_run), "--out", str(tmp_path), *QUIET]) == 1
    assert "A1" in capsys.readouterr().err
    assert main(["velocity", str(point_dd), "--out", str(tmp_path), *QUIET]) == 1
    assert main(["curves", str(tmp_path / "missing"), *QUIET]) == 1
    with pytest.raises(SystemExit):
        main(["nope"])


# --- A1 ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def a1_runs(run_factory: Callable[..., Path]) -> dict[str, Path]:
    return {
        "ursa": run_factory("a1-ursa", small_config("a1"), steps=300, prefill=150),
        "dd": run_factory("a1-dd", small_config("a1", mode="daydreamer"), steps=250, prefill=150),
        "vel": run_factory("a1-vel", small_config("a1", "velocity"), steps=300, prefill=150),
    }


@pytest.mark.slow
def test_a1_diversity_and_embedding(a1_runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "a1"
    assert main(["diversity", str(a1_runs["ursa"]), "--baseline", str(a1_runs["dd"]),
                 "--out", str(out), "--skills", "4", "--steps", "30", *QUIET]) == 0
    s = _json(out / "diversity.json")
    _png(out / "diversity.png")
    assert s["feature_key"] == "vae_input" and len(s["grids"]) == 12
    for r in s["runs"].values():
        assert 12 <= r["covered_cells"] <= r["total_cells"] == 12 * 20  # every joint has a mean
        assert sum(r["per_grid"].values()) == r["covered_cells"]
        assert all(1 <= v <= 4 for v in r["per_grid"].values())
    assert s["runs"]["ursa"]["mode"] == "ursa"
    assert main(["embedding", str(a1_runs["ursa"]), "--out", str(out), "--skills", "3",
                 "--steps", "20", *QUIET]) == 0
    e = _json(out / "embedding.json")
    assert e["skills"] == 3 and e["within_skill_spread"] >= 0


@pytest.mark.slow
def test_a1_archive_from_another_encoder_is_reencoded(a1_runs: dict[str, Path],
                                                      tmp_path: Path) -> None:
    import shutil

    run_dir = tmp_path / "copy"
    shutil.copytree(a1_runs["ursa"], run_dir)
    run = load_run(run_dir)
    policy, rep = run.require_policy(), run.require_repertoire()
    assert policy.vae is not None and rep.encoder_version == policy.vae_version
    assert "reencoded_from" not in run.extra
    # an archive saved under another encoder version (services save it on their own clock)
    rep.reencode(lambda x: policy.features(x) + 1.0, policy.vae_version + 7)
    rep.save(run_dir / "repertoire" / "archive.npz")
    again = load_run(run_dir)
    got = again.require_repertoire()
    assert again.extra["reencoded_from"] == policy.vae_version + 7
    assert got.encoder_version == policy.vae_version
    np.testing.assert_allclose(got.skills, policy.features(got.inputs), rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_a1_damage(a1_runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "dmg"
    assert main(["damage", str(a1_runs["ursa"]), str(a1_runs["vel"]), "--baseline",
                 str(a1_runs["dd"]), "--out", str(out), "--skills", "2", "--steps", "25",
                 *QUIET]) == 0
    s = _json(out / "damage.json")
    _png(out / "damage.png")
    scen = ["front_hip", "front_upper", "front_lower", "back_hip", "back_upper", "back_lower"]
    assert list(s["scenarios"]) == scen
    for label, n_runs in (("ursa", 2), ("baseline", 1)):
        for sc in scen:
            st = s["stats"][label][sc]
            assert st["runs"] == n_runs and math.isfinite(st["median"])
            assert st["min"] <= st["median"] <= st["max"]
    for r in s["runs"]:
        assert all(math.isfinite(x) for x in r["returns"])
        if r["label"] == "ursa":
            assert len(r["returns"]) == 2 and r["score"] == max(r["returns"])
            assert r["best_skill_id"] >= 0
    assert len(_csv(out / "damage.csv")) == 18


@pytest.mark.slow
def test_a1_velocity_and_curves(a1_runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "vel"
    assert main(["velocity", str(a1_runs["vel"]), "--out", str(out), "--grid", "3",
                 "--steps", "25", *QUIET]) == 0
    s = _json(out / "velocity.json")
    _png(out / "velocity.png")
    assert s["dims"] == ["forward velocity (m/s)", "yaw rate (rad/s)"]
    err = np.array(s["error"])
    assert err.shape == (3, 3, 2) and np.all(err >= 0) and np.all(np.isfinite(err))
    # the learned-feature run has no velocity skills
    assert main(["velocity", str(a1_runs["ursa"]), "--out", str(out), *QUIET]) == 1
    assert main(["curves", str(a1_runs["ursa"]), "--out", str(out), *QUIET]) == 0
    c = _json(out / "curves.json")
    assert c["env_steps"] == 300 and 0.0 <= c["final"]["violation_rate"] <= 1.0
    assert c["final"]["rescues_per_hour"] >= 0.0 and c["control_hz"] == 20.0
