"""Issue 6's end-to-end learning test: the point env trained across processes over the bus.

A real router, the repertoire service, the learner service and two unthrottled collectors (the
rate limiter of ``ursa.pace`` holds them to the learner's replay ratio) train with the recipe of
the learner-core tests (:mod:`tests.trained`, passed to every service as flags). The learner
stops updating after the same 3000 updates; SIGTERM writes its checkpoint and the repertoire's
archive, and the run directory is then judged with the same thresholds as the single-process
run (``tests/ursa/learner/test_learning.py``).
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from services.stack import StatsWatcher, running_stack, wait_for
from tests.trained import cli_args

# The learner-core tests, collected here again against this module's ``ursa_run``.
from tests.ursa.learner.test_learning import (  # noqa: F401
    assess,
    test_multipliers,
    test_safety_violations_below_a_third_of_random,
    test_skills_executed_within_delta,
    test_world_model_heldout_prediction_loss_falls,
)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(2400)]

UPDATES = 3000
"""Learner updates, as in the single-process run."""
RUN = "learn"


@pytest.fixture(scope="module")
def ursa_runs(ursa_run: dict[str, Any]) -> list[dict[str, Any]]:
    """The one run of this module, for the tests written over the seeds' runs."""
    return [ursa_run]


@pytest.fixture(scope="module")
def ursa_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("distributed")
    flags = cli_args("ursa-supervised")[4:]  # the stack adds --preset tiny --env point
    start = time.perf_counter()
    with running_stack(tmp, run_id=RUN) as st:
        # unthrottled collectors: the rate limiter (ursa.pace) holds them to the learner's ratio
        st.start_training(
            *flags,
            collectors=2,
            learner=("--max-updates", str(UPDATES), "--publish-every-s", "2"),
        )
        learner = st.procs["learner"]
        session = st.session()
        watcher = StatsWatcher(session, st.topics)
        progress: list[tuple[float, float, float]] = []

        def done() -> bool:
            ls = watcher.get("learner", "main")
            if ls is None:
                return False
            sc = ls.scalars
            row = (time.perf_counter() - start, sc.get("updates", 0.0), sc.get("replay_steps", 0.0))
            if not progress or row[0] - progress[-1][0] > 60:
                progress.append(row)
                print(f"  {row[0]:.0f} s: {row[1]:.0f} updates, replay {row[2]:.0f}", flush=True)
            return sc.get("updates", 0.0) >= UPDATES

        try:
            wait_for(done, 1500, f"{UPDATES} learner updates")
        except Exception:
            print(st.logs())
            raise
        stats = {
            k: watcher.get(*k)
            for k in (
                ("learner", "main"),
                ("collector", "c0"),
                ("collector", "c1"),
                ("repertoire", "main"),
            )
        }
        assert all(v is not None for v in stats.values()), stats
        watcher.close()
        session.close()
        assert learner.stop(60) == 0, learner.log()[-3000:]
    seconds = time.perf_counter() - start
    ls = stats[("learner", "main")]
    assert ls is not None
    for cid in ("c0", "c1"):
        assert ls.scalars[f"chunks/{cid}"] > 0
        assert ls.scalars[f"gaps/{cid}"] == 0 and ls.scalars[f"duplicates/{cid}"] == 0
    out = assess(
        st.run_dir,
        f"URSA over the bus ({seconds:.0f} s, replay "
        f"{ls.scalars.get('replay_steps', 0):.0f} steps)",
    )
    out["stats"] = stats
    return out
