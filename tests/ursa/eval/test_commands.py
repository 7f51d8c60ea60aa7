"""Every ``ursa eval`` command on small checkpoints: point env (fast) and short A1 runs (slow).
Checks that the files exist, and that their numbers agree with references computed here from
the run's own outputs (metrics rows, per-step CSVs, the archive) and with the behaviour they
measure (a frozen joint changes the return, coverage counts the cells the means fall in)."""

from __future__ import annotations

import csv
import json
import math
import shutil
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.ursa.eval._runs import small_config
from ursa.eval.cli import main
from ursa.eval.loading import iter_metrics, load_run
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


def _last_rows(run_dir: Path, service: str) -> list[dict[str, float]]:
    """The scalars of a service's metrics rows, in order."""
    return [r["scalars"] for r in iter_metrics(run_dir) if r["service"] == service]


def _check_velocity(out: Path, s: dict[str, Any]) -> None:
    """velocity.csv holds the target grid (row i·G + j: (axes[0][i], axes[1][j])), each
    error is |achieved − target|, the per-step error bounds it from above (|mean| ≤ mean |·|),
    and the JSON's error grid and means are the CSV's."""
    rows = _csv(out / "velocity.csv")  # written with 6 significant digits
    g = s["grid"]
    col = {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
    ax0, ax1 = (np.array(a) for a in s["axes"])
    np.testing.assert_allclose(col["target_0"], np.repeat(ax0, g), rtol=1e-5)
    np.testing.assert_allclose(col["target_1"], np.tile(ax1, g), rtol=1e-5)
    for k in (0, 1):
        err = col[f"error_{k}"]
        np.testing.assert_allclose(
            err, np.abs(col[f"achieved_{k}"] - col[f"target_{k}"]), rtol=1e-5, atol=1e-5
        )
        assert np.all(col[f"step_error_{k}"] >= err - 1e-5)
        np.testing.assert_allclose(np.array(s["error"])[:, :, k].ravel(), err, rtol=1e-5, atol=1e-6)
        assert s["error_mean"][k] == pytest.approx(err.mean(), rel=1e-5, abs=1e-6)
        assert s["step_error_mean"][k] == pytest.approx(
            col[f"step_error_{k}"].mean(), rel=1e-5, abs=1e-6
        )


def _check_spread(out: Path, e: dict[str, Any]) -> None:
    """within_skill_spread is the mean distance of a skill's embedded points to their centroid
    and between_skill_distance the mean distance between centroids, recomputed from the CSV."""
    rows = _csv(out / "embedding.csv")
    k, t = e["skills"], e["steps"]
    pts = np.array([[float(r["x"]), float(r["y"])] for r in rows]).reshape(k, t, 2)
    cent = pts.mean(1)
    spread = np.linalg.norm(pts - cent[:, None], axis=-1).mean()
    between = np.linalg.norm(cent[:, None] - cent[None], axis=-1)[~np.eye(k, dtype=bool)].mean()
    assert e["within_skill_spread"] == pytest.approx(spread, rel=1e-4) and spread > 0
    assert e["between_skill_distance"] == pytest.approx(between, rel=1e-4)


def _check_final_rates(run_dir: Path, c: dict[str, Any]) -> None:
    """The curves' final violation rate and rescues per hour, counted from the last two
    collector rows (rows 50 steps apart, more than the default window of 1/25 of the run)."""
    rows = _last_rows(run_dir, "collector")
    a, b = rows[-2], rows[-1]
    d = b["steps"] - a["steps"]
    assert d >= c["env_steps"] / 25
    f = c["final"]
    assert f["violation_rate"] == pytest.approx((b["unsafe_total"] - a["unsafe_total"]) / d)
    assert f["rescues_per_hour"] == pytest.approx(
        (b["rescues"] - a["rescues"]) / d * c["control_hz"] * 3600.0
    )


def _hand_cells(
    s: dict[str, Any], label: str, out: Path, safe_only: bool = False
) -> dict[str, Counter[tuple[int, ...]]]:
    """Grid name -> how many of ``label``'s mean features fall in each cell, counted here from
    diversity_means.csv and the grids' boxes in diversity.json (half-open cells, the last one
    closed; means outside the box in no cell); ``safe_only``: of the executions without an
    unsafe step."""
    key = s["feature_key"]
    rows = [r for r in _csv(out / "diversity_means.csv") if r["label"] == label]
    if safe_only:
        rows = [r for r in rows if float(r["violation_rate"]) == 0.0]
    cells: dict[str, Counter[tuple[int, ...]]] = {}
    for g in s["grids"]:
        count: Counter[tuple[int, ...]] = Counter()
        for r in rows:
            x = [float(r[f"mean_{key}_{d}"]) for d in g["dims"]]
            if all(lo <= v <= hi for v, lo, hi in zip(x, g["low"], g["high"], strict=True)):
                count[
                    tuple(
                        min(int((v - lo) / (hi - lo) * b), b - 1)
                        for v, lo, hi, b in zip(x, g["low"], g["high"], g["bins"], strict=True)
                    )
                ] += 1
        cells[g["name"]] = count
    return cells


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
    # the archive is the run's final repertoire: what its last metrics row reported
    archive = Repertoire.load(point_run / "repertoire" / "archive.npz")
    last = _last_rows(point_run, "repertoire")[-1]
    assert len(archive) == last["size"] > 1 and archive.commits == last["commits"]
    assert archive.delta() == pytest.approx(last["delta"], rel=1e-9)
    np.testing.assert_array_equal(archive.skills, run.repertoire.skills)
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
    argv = [
        "diversity",
        str(point_run),
        "--baseline",
        str(point_dd),
        "--out",
        str(out),
        "--skills",
        "12",
        "--steps",
        "30",
        "--bins",
        "10",
        *QUIET,
    ]
    assert main(argv) == 0
    s = _json(out / "diversity.json")
    _png(out / "diversity.png")
    assert s["env"] == "point" and s["feature_key"] == "position"
    rows = _csv(out / "diversity_means.csv")
    assert len(rows) == 36  # 12 executions of URSA, of the baseline and of random actions
    for label in ("ursa", "baseline", "random"):
        r = s["runs"][label]
        mine = [row for row in rows if row["label"] == label]
        means = np.array([[float(m["mean_position_0"]), float(m["mean_position_1"])] for m in mine])
        # hand count: the 10 × 10 cells of [-1, 1]² that the 12 mean positions fall in
        assert np.all(np.abs(means) <= 1.0)  # the arena
        cells = Counter(tuple(np.minimum(((p + 1.0) / 0.2).astype(int), 9).tolist()) for p in means)
        assert _hand_cells(s, label, out) == {"position": cells}
        assert r["covered_cells"] == len(cells) and r["total_cells"] == 100
        # only the executions without an unsafe step count towards the figure's coverage
        safe = _hand_cells(s, label, out, safe_only=True)["position"]
        assert r["safe_covered_cells"] == len(safe) <= len(cells)
        assert r["safe_executions"] == sum(float(m["violation_rate"]) == 0.0 for m in mine)
        # and they are the very cells (and counts) the cells CSV lists
        listed = {
            tuple(int(x) for x in c["cell"].split()): int(c["count"])
            for c in _csv(out / f"diversity_cells_{label}.csv")
            if int(c["count"]) > 0
        }
        assert listed == dict(cells)
        assert r["executions"] == len(mine) == 12
        assert r["return_mean"] == pytest.approx(
            np.mean([float(m["return"]) for m in mine]), rel=1e-5
        )
        assert r["violation_rate_mean"] == pytest.approx(
            np.mean([float(m["violation_rate"]) for m in mine]), rel=1e-5, abs=1e-6
        )
    runs = s["runs"]
    assert runs["baseline"]["mode"] == "daydreamer" and runs["random"]["mode"] == "random"
    assert 0.0 <= runs["ursa"]["within_delta_fraction"] <= 1.0
    assert "within_delta_fraction" not in runs["random"]
    assert s["ratio"] == runs["ursa"]["covered_cells"] / runs["baseline"]["covered_cells"]
    for key, other in (("safe_ratio", "baseline"), ("safe_ratio_random", "random")):
        if runs[other]["safe_covered_cells"]:
            assert s[key] == runs["ursa"]["safe_covered_cells"] / runs[other]["safe_covered_cells"]
    # random actions: the mean positions of 12 uniformly random walks differ
    rand = np.array([[float(m["mean_position_0"]), float(m["mean_position_1"])] for m in rows[24:]])
    assert len(np.unique(rand.round(6), axis=0)) == 12


def test_default_out_is_run_eval(point_run: Path) -> None:
    assert main(["embedding", str(point_run), "--skills", "3", "--steps", "15", *QUIET]) == 0
    s = _json(point_run / "eval" / "embedding.json")
    _png(point_run / "eval" / "embedding.png")
    assert s["method"] == "pca" and s["skills"] == 3 and s["steps"] == 15
    assert 0.0 <= sum(s["explained_variance"]) <= 1.0 + 1e-9
    rows = _csv(point_run / "eval" / "embedding.csv")
    assert len(rows) == 45 and all(math.isfinite(float(r["x"])) for r in rows)
    _check_spread(point_run / "eval", s)


def test_velocity_on_point_positions(point_run: Path, tmp_path: Path) -> None:
    # the point env's provided φ (position) is 2-D: the tracking evaluation applies as is
    out = tmp_path / "vel"
    assert (
        main(
            ["velocity", str(point_run), "--out", str(out), "--grid", "3", "--steps", "20", *QUIET]
        )
        == 0
    )
    s = _json(out / "velocity.json")
    _png(out / "velocity.png")
    assert np.array(s["error"]).shape == (3, 3, 2)
    _check_velocity(out, s)
    # the grid spans the 0.1 and 0.9 quantiles of the skills' mean positions, executed first
    # (the N_z most distinct skills, T steps each), not the repertoire's per-step extremes
    pts = np.array(s["grid_points"])
    rep = load_run(point_run).require_repertoire()
    assert s["grid_from"] == "achieved" and s["quantile"] == 0.1
    assert len(pts) == min(rep.config.n_z, len(rep)) and s["task"] is None
    for k in (0, 1):
        np.testing.assert_allclose(
            [s["axes"][k][0], s["axes"][k][-1]], np.quantile(pts[:, k], [0.1, 0.9]), rtol=1e-9
        )
    assert len(_csv(out / "velocity.csv")) == 9
    # the old box: the repertoire's entries, min to max
    assert (
        main(
            [
                "velocity",
                str(point_run),
                "--out",
                str(out),
                "--grid",
                "3",
                "--steps",
                "20",
                "--grid-from",
                "repertoire",
                "--quantile",
                "0",
                *QUIET,
            ]
        )
        == 0
    )
    s = _json(out / "velocity.json")
    np.testing.assert_allclose(
        [s["axes"][0][0], s["axes"][0][-1]], [rep.skills[:, 0].min(), rep.skills[:, 0].max()]
    )


def test_curves_point(point_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "curves"
    assert main(["curves", str(point_run), "--out", str(out), *QUIET]) == 0
    s = _json(out / "curves.json")
    _png(out / "curves.png")
    assert s["env_steps"] == 400
    f = s["final"]
    assert f["rescues_per_hour"] == 0.0  # the point env never rescues
    assert 1 < f["repertoire_size"] <= 300 and f["delta"] > 0 and math.isfinite(f["entropy_bound"])
    assert math.isfinite(f["return"])
    curves = {r["curve"] for r in _csv(out / "curves.csv")}
    assert {
        "violation_rate",
        "rescues_per_hour",
        "return",
        "repertoire_size",
        "delta",
        "entropy_bound",
    } <= curves


def test_curves_from_hand_written_metrics(point_run: Path, tmp_path: Path) -> None:
    """Two collectors' counters, 100 steps per row each: total steps 0, 200, 400, 600, 800,
    unsafe steps 0, 10, 10, 30, 60, rescues 0, 0, 1, 1, 4. With a window of 300 steps each
    rate is taken from the latest row at least 300 steps back (the first row when none is)."""
    run_dir = tmp_path / "run"
    shutil.copytree(point_run, run_dir)
    rows = []
    for cid, unsafe, rescues in (
        ("c0", [0, 10, 10, 30, 40], [0, 0, 1, 1, 3]),
        ("c1", [0, 0, 0, 0, 20], [0, 0, 0, 0, 1]),
    ):
        for i in range(5):
            rows.append(
                {
                    "t": 1000.0 + i,
                    "service": "collector",
                    "id": cid,
                    "labels": {},
                    "scalars": {
                        "steps": 100.0 * i,
                        "unsafe_total": unsafe[i],
                        "rescues": rescues[i],
                    },
                }
            )
    (run_dir / "metrics" / "collector-serial.jsonl").write_text(
        "".join(json.dumps(r) + "\n" for r in rows)
    )
    out = tmp_path / "curves"
    assert (
        main(
            [
                "curves",
                str(run_dir),
                "--out",
                str(out),
                "--window",
                "300",
                "--control-hz",
                "10",
                *QUIET,
            ]
        )
        == 0
    )
    s = _json(out / "curves.json")
    assert s["env_steps"] == 800
    csv_rows = _csv(out / "curves.csv")
    curve = {
        name: np.array(
            [[float(r["env_steps"]), float(r["value"])] for r in csv_rows if r["curve"] == name]
        )
        for name in ("violation_rate", "rescues_per_hour")
    }
    # 200: (10-0)/200; 400: (10-0)/400; 600: (30-10)/400; 800: (60-10)/400
    np.testing.assert_allclose(
        curve["violation_rate"], [[200, 0.05], [400, 0.025], [600, 0.05], [800, 0.125]]
    )
    # per step × 10 steps/s × 3600 s/h: 0/200, 1/400, 1/400, 3/400
    np.testing.assert_allclose(
        curve["rescues_per_hour"], [[200, 0.0], [400, 90.0], [600, 90.0], [800, 270.0]]
    )
    assert s["final"]["violation_rate"] == pytest.approx(0.125)
    assert s["final"]["rescues_per_hour"] == pytest.approx(270.0)
    assert s["mean"]["violation_rate"] == pytest.approx(0.0625)


def test_all_runs_what_applies(
    point_run: Path, point_dd: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "all"
    assert (
        main(
            [
                "all",
                str(point_run),
                "--baseline",
                str(point_dd),
                "--out",
                str(out),
                "--skills",
                "4",
                "--steps",
                "10",
                *QUIET,
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["ran"] == ["curves", "embedding", "diversity", "velocity"]  # no A1: no damage
    for name in ("curves", "embedding", "diversity", "velocity"):
        _png(out / f"{name}.png")
        _json(out / f"{name}.json")


def test_errors_are_reported(
    point_run: Path, point_dd: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
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
    assert (
        main(
            [
                "diversity",
                str(a1_runs["ursa"]),
                "--baseline",
                str(a1_runs["dd"]),
                "--out",
                str(out),
                "--skills",
                "4",
                "--steps",
                "30",
                *QUIET,
            ]
        )
        == 0
    )
    s = _json(out / "diversity.json")
    _png(out / "diversity.png")
    assert s["feature_key"] == "vae_input" and len(s["grids"]) == 12
    for label, r in s["runs"].items():
        assert r["total_cells"] == 12 * 20
        # per joint: the cells its 4 mean angles fall in, counted from the means CSV
        hand = _hand_cells(s, label, out)
        assert r["per_grid"] == {name: len(c) for name, c in hand.items()}
        assert r["covered_cells"] == sum(len(c) for c in hand.values())
        assert r["outside_points"] == sum(4 - sum(c.values()) for c in hand.values())
    assert s["runs"]["ursa"]["mode"] == "ursa"
    assert (
        main(
            [
                "embedding",
                str(a1_runs["ursa"]),
                "--out",
                str(out),
                "--skills",
                "3",
                "--steps",
                "20",
                *QUIET,
            ]
        )
        == 0
    )
    e = _json(out / "embedding.json")
    assert e["skills"] == 3
    _check_spread(out, e)


@pytest.mark.slow
def test_a1_archive_from_another_encoder_is_reencoded(
    a1_runs: dict[str, Path], tmp_path: Path
) -> None:
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
    assert (
        main(
            [
                "damage",
                str(a1_runs["ursa"]),
                str(a1_runs["vel"]),
                "--baseline",
                str(a1_runs["dd"]),
                "--out",
                str(out),
                "--skills",
                "2",
                "--steps",
                "25",
                *QUIET,
            ]
        )
        == 0
    )
    s = _json(out / "damage.json")
    _png(out / "damage.png")
    scen = ["front_hip", "front_upper", "front_lower", "back_hip", "back_upper", "back_lower"]
    assert list(s["scenarios"]) == scen
    for label, n_runs in (("ursa", 2), ("baseline", 1)):
        for sc in scen:
            st = s["stats"][label][sc]
            assert st["runs"] == n_runs and math.isfinite(st["median"])
            assert st["min"] <= st["median"] <= st["max"]
    reps = {p.name: load_run(p).require_repertoire() for p in (a1_runs["ursa"], a1_runs["vel"])}
    assert s["fresh_trials"] == 3
    for r in s["runs"]:
        assert all(math.isfinite(x) for x in [*r["returns"], *r["fresh_returns"]])
        # one protocol for both: K = 2 selection trials, the score is the mean of 3 fresh
        # trials of the selected candidate (never the selection trials' best)
        assert len(r["returns"]) == 2 and len(r["fresh_returns"]) == 3
        assert r["score"] == pytest.approx(np.mean(r["fresh_returns"]), rel=1e-12)
        assert not set(r["fresh_returns"]) & set(r["returns"])  # other action noise
        if r["label"] == "ursa":
            # the selected skill is in the archive
            np.testing.assert_allclose(
                r["best_skill"], reps[r["run"]].get(np.array([r["best_skill_id"]]))[0], rtol=1e-6
            )
        else:
            assert r["best_skill_id"] == -1 and r["best_skill"] == []
    assert len(_csv(out / "damage.csv")) == 18
    # the same skills and seed, intact: each frozen joint changes every skill's return, and a
    # scenario evaluated twice gives the same returns (only the damage differs between them)
    again = tmp_path / "dmg-intact"
    assert (
        main(
            [
                "damage",
                str(a1_runs["ursa"]),
                "--scenarios",
                "intact",
                "front_hip",
                "back_lower",
                "--out",
                str(again),
                "--skills",
                "2",
                "--steps",
                "25",
                *QUIET,
            ]
        )
        == 0
    )
    by = {r["scenario"]: np.array(r["returns"]) for r in _json(again / "damage.json")["runs"]}
    first = {
        r["scenario"]: np.array(r["returns"]) for r in s["runs"] if r["run"] == a1_runs["ursa"].name
    }
    for sc in ("front_hip", "back_lower"):
        np.testing.assert_allclose(by[sc], first[sc], rtol=1e-9)
        assert np.all(np.abs(by[sc] - by["intact"]) > 1e-6), (sc, by[sc], by["intact"])


@pytest.mark.slow
def test_a1_velocity_and_curves(a1_runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "vel"
    assert (
        main(
            [
                "velocity",
                str(a1_runs["vel"]),
                "--out",
                str(out),
                "--grid",
                "3",
                "--steps",
                "25",
                "--skills",
                "4",
                "--any-task",  # a forward-task run: Figure 6 proper is the posture task's
                *QUIET,
            ]
        )
        == 0
    )
    assert main(["velocity", str(a1_runs["vel"]), "--out", str(out), *QUIET]) == 1
    s = _json(out / "velocity.json")
    _png(out / "velocity.png")
    assert s["dims"] == ["forward velocity (m/s)", "yaw rate (rad/s)"]
    assert s["task"] == "forward" and len(s["grid_points"]) == 4
    assert np.array(s["error"]).shape == (3, 3, 2)
    _check_velocity(out, s)
    # the learned-feature run has no velocity skills
    assert main(["velocity", str(a1_runs["ursa"]), "--out", str(out), *QUIET]) == 1
    assert main(["curves", str(a1_runs["ursa"]), "--out", str(out), *QUIET]) == 0
    c = _json(out / "curves.json")
    assert c["env_steps"] == 300 and c["control_hz"] == 20.0
    _check_final_rates(a1_runs["ursa"], c)
