"""Figure 4's claim on the point env: URSA's skills cover at least five times as many cells of
the arena as the ``daydreamer`` baseline's single behaviour, both trained with the learner's
point-env recipe and the same budget, and evaluated the same way (``ursa eval diversity``).

Opt-in like the learner's own learning tests (docs/NOTES.md: the current learner needs more
updates than CI time allows on 2 shared cores): ``URSA_LEARNING_TESTS=1``. Measured with this
recipe and budget: see docs/eval.md.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from tests.ursa.eval._runs import train_point
from tests.ursa.learner.test_learning import POINT, SERIAL
from ursa.eval.cli import main

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        os.environ.get("URSA_LEARNING_TESTS") != "1",
        reason="learning thresholds not yet met in CI time (docs/NOTES.md); "
        "URSA_LEARNING_TESTS=1 runs them",
    ),
]

#: The learner's point-env recipe (tests/ursa/learner/test_learning.py: POINT, SERIAL), the
#: same for both runs; only the mode differs.
LEARNER: dict[str, object] = {
    f.name: getattr(POINT, f.name)
    for f in dataclasses.fields(POINT)
    if f.name not in ("mode", "skill_dim")  # the env sets D (2: the position)
}
PREFILL = SERIAL.prefill
STEPS = int(os.environ.get("URSA_EVAL_LEARN_STEPS", PREFILL + 400))
"""Env steps per run: the prefill, then 400 on-policy steps (train_ratio 128: 600 updates, 500
of them right after the prefill). A daydreamer agent has settled on its one behaviour by then."""
REPERTOIRE = {"size": SERIAL.repertoire_size, "n_z": SERIAL.n_z}
SKILL_PERIOD = SERIAL.skill_period
#: Evaluation: the N_z = 100 most distinct skills, T = the skill period, a 20 × 20 arena grid.
SKILLS, BINS = SERIAL.n_z, 20


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    root = str(tmp_path_factory.mktemp("learned"))
    jobs = [(root, name, mode, LEARNER, STEPS, PREFILL, REPERTOIRE, SKILL_PERIOD)
            for name, mode in (("ursa", "ursa-supervised"), ("daydreamer", "daydreamer"))]
    if (os.cpu_count() or 1) >= 2:  # one process per run: the two trainings share nothing
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
            paths = list(ex.map(train_point, jobs))
    else:
        paths = [train_point(j) for j in jobs]
    return {"ursa": paths[0], "daydreamer": paths[1]}


@pytest.mark.timeout(1800)
def test_ursa_covers_five_times_the_cells_of_daydreamer(trained: dict[str, str],
                                                        tmp_path: Path) -> None:
    out = tmp_path / "diversity"
    assert main(["diversity", trained["ursa"], "--baseline", trained["daydreamer"],
                 "--out", str(out), "--skills", str(SKILLS), "--steps", str(SKILL_PERIOD),
                 "--bins", str(BINS), "--no-progress"]) == 0
    s = json.loads((out / "diversity.json").read_text())
    u, d = s["runs"]["ursa"], s["runs"]["baseline"]
    print(f"\ncovered cells: ursa {u['covered_cells']} / daydreamer {d['covered_cells']} of "
          f"{u['total_cells']} ({u['updates']} / {d['updates']} updates); ursa within δ "
          f"{u.get('within_delta_fraction')}, returns {u['return_mean']:.1f} / "
          f"{d['return_mean']:.1f}")
    assert u["nonfinite_actions"] == 0 and d["nonfinite_actions"] == 0
    assert u["executions"] == d["executions"] == SKILLS
    assert d["covered_cells"] >= 1
    assert u["covered_cells"] >= 5 * d["covered_cells"]
