"""Issue 6 faults over real processes: collector SIGKILL and rejoin, learner SIGKILL and resume,
router restart."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest

from services.learner.replay_store import read_all
from tests.stack import Stack, StatsWatcher, running_stack, wait_for

pytestmark = pytest.mark.slow

# fast learner settings so that weights and checkpoints come within seconds
LEARNER_ARGS = ("--min-replay", "500", "--publish-every-s", "1", "--checkpoint-every-s", "3")
COLLECTOR_ARGS = ("--realtime-factor", "10")  # 200 steps/s: leaves CPU to the learner


def _scalar(w: StatsWatcher, service: str, sid: str, key: str) -> float:
    s = w.get(service, sid)
    return float(s.scalars.get(key, -1)) if s is not None else -1.0


def _alive_collectors(w: StatsWatcher) -> set[str]:
    s = w.get("learner", "main")
    if s is None or not s.labels.get("collectors_alive"):
        return set()
    return set(s.labels["collectors_alive"].split(","))


def _start(st: Stack) -> None:
    st.start_router()
    st.start("repertoire", "services.repertoire")
    st.start("learner", "services.learner", *LEARNER_ARGS)
    for i in range(2):
        st.start(f"c{i}", "services.collector", "--collector-id", f"c{i}", "--seed", str(i),
                 *COLLECTOR_ARGS)


def test_collector_killed_leaves_others_running_and_rejoins_with_latest_weights(
    tmp_path: Path,
) -> None:
    with running_stack(tmp_path) as st:
        _start(st)
        session = st.session()
        w = StatsWatcher(session, st.topics)
        wait_for(lambda: _alive_collectors(w) == {"c0", "c1"}, 60, "both collectors alive", 0.5)
        wait_for(lambda: _scalar(w, "collector", "c0", "policy_version") > 0, 120,
                 "trained weights reaching the collectors", 0.5)

        st.procs["c0"].kill(signal.SIGKILL)
        steps_c1 = _scalar(w, "collector", "c1", "steps")
        wait_for(lambda: _alive_collectors(w) == {"c1"}, 30, "the learner to see c0 leave", 0.5)
        wait_for(lambda: _scalar(w, "collector", "c1", "steps") > steps_c1 + 200, 30,
                 "c1 to keep stepping", 0.5)
        assert st.procs["learner"].alive() and st.procs["repertoire"].alive()

        st.start("c0", "services.collector", "--collector-id", "c0", "--seed", "0",
                 *COLLECTOR_ARGS)
        wait_for(lambda: _alive_collectors(w) == {"c0", "c1"}, 60, "c0 to rejoin", 0.5)

        def rejoined_with_latest() -> bool:
            cs = w.get("collector", "c0")
            ls = w.get("learner", "main")
            return bool(cs and ls and cs.scalars["incarnation"] == 1
                        and cs.scalars["policy_version"] > 0
                        and cs.scalars["policy_version"] >= ls.scalars["policy_version"] - 200)

        wait_for(rejoined_with_latest, 60, "c0 to act with the latest weights", 0.5)
        ls = w.get("learner", "main")
        assert ls is not None and ls.scalars["duplicates/c0"] == 0
        w.close()
        session.close()


def test_learner_killed_resumes_from_checkpoint_with_its_replay(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        _start(st)
        session = st.session()
        w = StatsWatcher(session, st.topics)
        ckpt = st.run_dir / "checkpoints" / "learner.pt"
        wait_for(lambda: ckpt.exists() and _scalar(w, "learner", "main", "updates") >= 5, 180,
                 "a checkpoint after a few updates", 0.5)
        time.sleep(4)  # let another checkpoint land after more updates
        st.procs["learner"].kill(signal.SIGKILL)
        st.procs["learner"].popen.wait(10)
        written = sum(int(c.obs.shape[0]) for c in read_all(st.run_dir / "replay"))
        state = (st.run_dir / "checkpoints" / "learner_state.json").read_text()
        ckpt_updates = json.loads(state)["updates"]
        assert written > 0 and ckpt_updates > 0

        restarted_at = time.time()
        st.start("learner", "services.learner", *LEARNER_ARGS)

        def restarted() -> object:
            s = w.get("learner", "main")  # stats of a process started after the restart
            if s is not None and s.header.stamp - s.scalars["uptime_s"] >= restarted_at - 0.5:
                return s
            return None

        first = wait_for(restarted, 120, "the restarted learner's stats", 0.1)
        assert first.scalars["updates"] >= ckpt_updates
        assert first.scalars["replay_steps"] >= written
        assert "resumed from checkpoint" in st.procs["learner"].log()
        wait_for(lambda: _scalar(w, "learner", "main", "updates") > ckpt_updates + 2, 120,
                 "training to go on", 0.5)
        w.close()
        session.close()


def test_router_restart_everyone_reconnects_and_data_flows(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        _start(st)
        session = st.session()
        w = StatsWatcher(session, st.topics)
        wait_for(lambda: _scalar(w, "learner", "main", "chunks/c1") > 10, 60, "data flowing", 0.5)
        st.procs["router"].stop()
        time.sleep(3)
        st.start_router()
        before = {k: _scalar(w, "learner", "main", f"chunks/{k}") for k in ("c0", "c1")}
        rep_before = _scalar(w, "repertoire", "main", "commits")
        wait_for(lambda: all(_scalar(w, "learner", "main", f"chunks/{k}") > before[k] + 20
                             for k in ("c0", "c1")), 60, "chunks after the restart", 0.5)
        wait_for(lambda: _scalar(w, "repertoire", "main", "commits") > rep_before, 60,
                 "features after the restart", 0.5)
        wait_for(lambda: _alive_collectors(w) == {"c0", "c1"}, 30, "liveliness restored", 0.5)
        ls = w.get("learner", "main")
        assert ls is not None
        # the collectors held their chunks while the router was down: nothing was lost
        assert ls.scalars["missing/c0"] == 0 and ls.scalars["missing/c1"] == 0
        for name, p in st.procs.items():
            assert p.alive(), f"{name} died:\n{st.logs()}"
        w.close()
        session.close()
