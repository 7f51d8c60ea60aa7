"""``ursa eval adapt`` on a tiny point-env run (fast) and a short A1 run (slow): files, the
cached intact map, ITE's first trial and the curves, and that the figure's numbers are the
trials' (recomputed from the CSV); scenario parsing for any frozen joint."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.ursa.eval._runs import small_config
from ursa import adapt
from ursa.envs.a1 import DAMAGE_SCENARIOS
from ursa.eval.adapt import parse_scenario
from ursa.eval.cli import main

pytestmark = pytest.mark.timeout(600)
QUIET = ["--no-progress"]


def _json(path: Path) -> dict[str, Any]:
    assert path.is_file(), path
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def test_scenarios_express_any_frozen_joint() -> None:
    for name, joints in DAMAGE_SCENARIOS.items():
        assert parse_scenario(name).frozen == joints
    assert parse_scenario("intact").frozen == ()
    assert parse_scenario("FL_lower").frozen == (5,)
    s = parse_scenario("RL_hip_joint+3")
    assert s.frozen == (3, 9) and s.label == "FL_hip+RL_hip"
    assert parse_scenario("11,0").frozen == (0, 11)
    for bad in ("12", "FX_hip", "front"):
        with pytest.raises(ValueError):
            parse_scenario(bad)


@pytest.fixture(scope="module")
def point_run(run_factory: Callable[..., Path]) -> Path:
    return run_factory("point-ursa", small_config("point"), steps=400, prefill=200)


@pytest.fixture(scope="module")
def point_dd(run_factory: Callable[..., Path]) -> Path:
    return run_factory("point-dd", small_config("point", mode="daydreamer"), steps=300, prefill=200)


def _check(out: Path, s: dict[str, Any], budget: int) -> None:
    assert (out / "adapt.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    prior = np.asarray(s["map"]["returns"])
    ids = s["map"]["skill_ids"]
    with open(out / "adapt.csv") as f:
        rows = list(csv.DictReader(f))
    for label, e in s["scenarios"].items():
        for method in ("ite", "random"):
            curves = []
            for r in e[method]["runs"]:
                rets = [t["return"] for t in r["trials"]]
                assert 1 <= r["n_trials"] == len(rets) <= budget
                assert r["chosen_return"] == max(rets)
                assert all(np.isfinite(rets))
                got = [
                    float(x["return"])
                    for x in rows
                    if x["method"] == method
                    and x["scenario"] == label
                    and int(x["seed"]) == r["seed"]
                ]
                np.testing.assert_allclose(got, rets, rtol=1e-5, atol=1e-5)
                curves.append(adapt.best_so_far(np.asarray(rets), budget))
                skills = [t["skill_id"] for t in r["trials"]]
                assert len(set(skills)) == len(skills)  # no skill tried twice
                assert set(skills) <= set(ids)
            c = e[method]["best_so_far"]
            np.testing.assert_allclose(c["median"], np.median(curves, 0))
            np.testing.assert_allclose(c["min"], np.min(curves, 0))
            assert all(np.diff(c["median"]) >= -1e-12)
        for r in e["ite"]["runs"]:
            # the first trial is the best skill of the map (UCB with equal σ everywhere)
            assert r["trials"][0]["skill_id"] == ids[int(np.argmax(prior))]
            assert r["trials"][0]["predicted"] == pytest.approx(prior.max())
            assert r["stop_reason"] in adapt.STOP_REASONS
        ref = e["reference"]
        assert ref["best_return"] == pytest.approx(max(ref["returns"]))
        for method in ("ite", "random"):
            for r in e[method]["runs"]:
                hit = adapt.trials_to_reach(
                    np.asarray([t["return"] for t in r["trials"]]), ref["target"]
                )
                assert r["trials_to_reach"] == hit


def test_adapt_point(point_run: Path, point_dd: Path, tmp_path: Path) -> None:
    out = tmp_path / "a"
    argv = ["adapt", str(point_run), "--baseline", str(point_dd), "--out", str(out)]
    argv += ["--skills", "12", "--steps", "20", "--seeds", "3", "--budget", "5", *QUIET]
    assert main(argv) == 0
    s = _json(out / "adapt.json")
    assert list(s["scenarios"]) == ["intact"] and not s["map"]["cached"]
    assert s["skills"] == 12 and len(s["map"]["returns"]) == 12
    _check(out, s, 5)
    dd = s["scenarios"]["intact"]["daydreamer"]
    assert dd["n"] == 3 and dd["min"] <= dd["median"] <= dd["max"]
    # the map is cached in the run directory and read back, identical, on the next run
    cache = Path(s["map"]["path"])
    assert cache.is_file() and cache.parent == point_run / "eval" / "adapt"
    out2 = tmp_path / "b"
    argv2 = ["adapt", str(point_run), "--out", str(out2), "--skills", "12", "--steps", "20"]
    assert main([*argv2, "--seeds", "2", "--budget", "4", *QUIET]) == 0
    s2 = _json(out2 / "adapt.json")
    assert s2["map"]["cached"] and s2["map"]["returns"] == s["map"]["returns"]
    assert "daydreamer" not in s2["scenarios"]["intact"]
    # another T is another map
    out3 = tmp_path / "c"
    argv3 = ["adapt", str(point_run), "--out", str(out3), "--skills", "12", "--steps", "21"]
    assert main([*argv3, "--seeds", "1", "--budget", "2", "--no-reference", *QUIET]) == 0
    s3 = _json(out3 / "adapt.json")
    assert not s3["map"]["cached"] and s3["map"]["key"] != s["map"]["key"]


def test_adapt_errors(point_run: Path, point_dd: Path, tmp_path: Path) -> None:
    o = ["--out", str(tmp_path), *QUIET]
    assert main(["adapt", str(point_dd), *o]) == 1  # no skills
    assert main(["adapt", str(point_run), "--scenarios", "front_hip", *o]) == 1  # point: no joints
    assert main(["adapt", str(point_run), "--scenarios", "FX_hip", *o]) == 1


@pytest.mark.slow
def test_adapt_a1(run_factory: Callable[..., Path], tmp_path: Path) -> None:
    run = run_factory("a1-ursa", small_config("a1"), steps=300, prefill=150)
    dd = run_factory("a1-dd", small_config("a1", mode="daydreamer"), steps=250, prefill=150)
    out = tmp_path / "a1"
    argv = ["adapt", str(run), "--baseline", str(dd), "--out", str(out), "--skills", "6"]
    argv += ["--steps", "30", "--seeds", "2", "--budget", "3", "--scenarios", "front_upper"]
    assert main([*argv, "FL_lower+RR_hip", *QUIET]) == 0
    s = _json(out / "adapt.json")
    assert list(s["scenarios"]) == ["front_upper", "FL_lower+RR_hip"]
    assert s["scenarios"]["FL_lower+RR_hip"]["frozen_joints"] == [5, 6]
    _check(out, s, 3)
    intact = np.asarray(s["map"]["returns"])
    damaged = np.asarray(s["scenarios"]["front_upper"]["reference"]["returns"])
    assert not np.allclose(intact, damaged)  # the frozen joint changes what the skills give
