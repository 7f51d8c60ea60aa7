"""Figure 4's claim on the point env: URSA's skills cover at least five times as many cells of
the arena as the ``daydreamer`` baseline's single behaviour, both trained with the learner's
point-env recipe and the same budget (the session's runs of :mod:`tests.trained`), and
evaluated the same way (``ursa eval diversity``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.trained import N_Z, SKILL_PERIOD
from ursa.eval.cli import main

pytestmark = pytest.mark.slow

#: Evaluation: the N_z = 100 most distinct skills, T = the skill period, a 20 × 20 arena grid.
SKILLS, BINS = N_Z, 20


@pytest.fixture(scope="module")
def trained(point_runs: dict[str, Any]) -> dict[str, str]:
    return {name: str(path) for name, path in point_runs["runs"].items()}


@pytest.mark.timeout(1800)
def test_ursa_covers_five_times_the_cells_of_daydreamer(
    trained: dict[str, str], tmp_path: Path
) -> None:
    out = tmp_path / "diversity"
    assert (
        main(
            [
                "diversity",
                trained["ursa"],
                "--baseline",
                trained["daydreamer"],
                "--out",
                str(out),
                "--skills",
                str(SKILLS),
                "--steps",
                str(SKILL_PERIOD),
                "--bins",
                str(BINS),
                "--no-progress",
            ]
        )
        == 0
    )
    s = json.loads((out / "diversity.json").read_text())
    u, d = s["runs"]["ursa"], s["runs"]["baseline"]
    print(
        f"\ncovered cells: ursa {u['covered_cells']} / daydreamer {d['covered_cells']} of "
        f"{u['total_cells']} ({u['updates']} / {d['updates']} updates); ursa within δ "
        f"{u.get('within_delta_fraction')}, returns {u['return_mean']:.1f} / "
        f"{d['return_mean']:.1f}"
    )
    assert u["nonfinite_actions"] == 0 and d["nonfinite_actions"] == 0
    assert u["executions"] == d["executions"] == SKILLS
    assert d["covered_cells"] >= 1
    assert u["covered_cells"] >= 5 * d["covered_cells"]
