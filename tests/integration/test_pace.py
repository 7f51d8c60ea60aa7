"""The rate limiter over the bus (ursa.pace): a router, the repertoire, the learner and two
collectors of the tiny point preset. With ``pace=wait`` the collectors pause so that the
learner's replay ratio stays within the tolerance of its target; with ``pace=free`` (a real
robot) they never wait and the ratio falls far below it; a killed learner never holds them."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

from services.stack import StatsWatcher, running_stack, wait_for
from ursa.config import preset

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

TARGET = preset("tiny", "point").learner.train_ratio
TOLERANCE = preset("tiny", "point").collector.pace_tolerance


def _stack(st, pace: str, collector: tuple[str, ...] = ()) -> None:  # type: ignore[no-untyped-def]
    flags = ["--core.collector.pace", pace]
    st.start_training(*flags, collectors=2, learner=("--stats-hz", "5"), collector=collector)


def test_waiting_collectors_keep_the_replay_ratio_at_its_target(tmp_path: Path) -> None:
    with running_stack(tmp_path, run_id="pace") as st:
        _stack(st, "wait")
        session = st.session()  # kept: a dropped zenoh session closes
        watcher = StatsWatcher(session, st.topics)
        try:

            def trained(n: float) -> bool:
                ls = watcher.get("learner", "main")
                return ls is not None and ls.scalars.get("updates", 0) >= n

            # the prefill (min_replay) is collected freely; the learner then catches up. The
            # ratio is held over the steps since the first update, within the limiter's slack
            # (4 updates' worth) and the chunks in flight: ~5 % of 250 updates' samples
            wait_for(lambda: trained(250), 300, "250 updates", every=0.5)
            ratios = []
            for n in (275, 300):
                wait_for(functools.partial(trained, n), 120, f"{n} updates", every=0.5)
                ls = watcher.get("learner", "main")
                assert ls is not None
                ratios.append(ls.scalars["replay_ratio_paced"])
            waited = [watcher.get("collector", f"c{i}") for i in range(2)]
            print(
                f"\nreplay ratio {ratios} (target {TARGET}); collectors waited "
                f"{[w.scalars['pace_wait_s'] if w else None for w in waited]} s"
            )
            for r in ratios:
                assert abs(r - TARGET) <= TOLERANCE * TARGET + 1e-9, (ratios, st.logs())
            for w in waited:
                assert w is not None and w.scalars["pace_wait_s"] > 1.0

            # a killed learner never holds the collectors: they resume within stale_s
            st.procs["learner"].kill()
            steps = {i: watcher.get("collector", f"c{i}").scalars["steps"] for i in range(2)}  # type: ignore[union-attr]

            def resumed() -> bool:
                now = [watcher.get("collector", f"c{i}") for i in range(2)]
                return all(
                    c is not None
                    and c.scalars["steps"] > steps[i] + 500
                    and c.scalars["pace_waiting"] == 0.0
                    for i, c in enumerate(now)
                )

            wait_for(resumed, 60, "collectors stepping again without a learner")
        finally:
            watcher.close()
            session.close()


def test_free_collectors_never_wait(tmp_path: Path) -> None:
    with running_stack(tmp_path, run_id="free") as st:
        # free collectors step at a robot's pace, not as fast as the CPU allows (which would
        # starve the learner on a small machine): 10x real time is 200 steps/s each, more than
        # the tiny learner's ratio lets it consume (16 steps per update)
        _stack(st, "free", collector=("--realtime-factor", "10"))
        session = st.session()  # kept: a dropped zenoh session closes
        watcher = StatsWatcher(session, st.topics)
        try:

            def trained() -> bool:
                ls = watcher.get("learner", "main")
                return ls is not None and ls.scalars.get("updates", 0) >= 100

            wait_for(trained, 300, "100 updates", every=0.5)
            ls = watcher.get("learner", "main")
            assert ls is not None and ls.scalars["pace_engaged"] == 0.0
            for i in range(2):
                c = watcher.get("collector", f"c{i}")
                assert c is not None and c.scalars["pace_wait_s"] == 0.0
            # unthrottled collectors outrun the learner: the ratio it reaches is far below
            assert ls.scalars["replay_ratio"] < 0.5 * TARGET, ls.scalars["replay_ratio"]
        finally:
            watcher.close()
            session.close()
