"""Issue 6 faults over real processes: collector SIGKILL and rejoin, learner SIGKILL and resume,
router restart."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest
import torch

from proto import ursa_pb2 as pb
from services.common.bus import Presence
from services.learner.replay_store import read_all
from services.stack import Stack, StatsWatcher, running_stack, wait_for

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
    st.start_training(collectors=2, learner=LEARNER_ARGS, collector=COLLECTOR_ARGS)


def test_collector_killed_leaves_others_running_and_rejoins_with_latest_weights(
    tmp_path: Path,
) -> None:
    with running_stack(tmp_path) as st:
        _start(st)
        session = st.session()
        w = StatsWatcher(session, st.topics)
        wait_for(lambda: _alive_collectors(w) == {"c0", "c1"}, 60, "both collectors alive", 0.5)
        wait_for(
            lambda: _scalar(w, "collector", "c0", "policy_version") > 0,
            120,
            "trained weights reaching the collectors",
            0.5,
        )

        st.procs["c0"].kill(signal.SIGKILL)
        steps_c1 = _scalar(w, "collector", "c1", "steps")
        wait_for(lambda: _alive_collectors(w) == {"c1"}, 30, "the learner to see c0 leave", 0.5)
        wait_for(
            lambda: _scalar(w, "collector", "c1", "steps") > steps_c1 + 200,
            30,
            "c1 to keep stepping",
            0.5,
        )
        assert st.procs["learner"].alive() and st.procs["repertoire"].alive()

        st.start("c0", "services.collector", "--collector-id", "c0", "--seed", "0", *COLLECTOR_ARGS)
        wait_for(lambda: _alive_collectors(w) == {"c0", "c1"}, 60, "c0 to rejoin", 0.5)

        def rejoined_with_latest() -> bool:
            cs = w.get("collector", "c0")
            ls = w.get("learner", "main")
            return bool(
                cs
                and ls
                and cs.scalars["incarnation"] == 1
                and cs.scalars["policy_version"] > 0
                and cs.scalars["policy_version"] >= ls.scalars["policy_version"] - 200
            )

        wait_for(rejoined_with_latest, 60, "c0 to act with the latest weights", 0.5)
        ls = w.get("learner", "main")
        assert ls is not None and ls.scalars["duplicates/c0"] == 0
        w.close()
        session.close()


# λ2's floor on, aiming at no violation at all: it rises at every update by 0.5 × the
# collectors' pooled violation rate (the point env's early policies: a few per cent)
FLOOR_ARGS = ("--core.learner.lambda2-floor-lr", "0.5", "--core.learner.lambda2-floor-target", "0")
RESTART_UPDATES = 3
"""Updates the restarted learner may run: a fresh floor stays under 3 × 0.5 × its rate."""


def _ckpt_floor(ckpt: Path) -> float:
    try:  # checkpoints are written atomically: a file that exists is whole
        return float(torch.load(ckpt, weights_only=True)["lam2_floor"])
    except FileNotFoundError:
        return -1.0


def test_learner_killed_resumes_from_checkpoint_with_its_replay(tmp_path: Path) -> None:
    with running_stack(tmp_path) as st:
        st.start_training(
            collectors=2, learner=(*LEARNER_ARGS, *FLOOR_ARGS), collector=COLLECTOR_ARGS
        )
        session = st.session()
        w = StatsWatcher(session, st.topics)
        ckpt = st.run_dir / "checkpoints" / "learner.pt"
        wait_for(
            lambda: _scalar(w, "learner", "main", "updates") >= 5 and _ckpt_floor(ckpt) >= 0.4,
            180,
            "a checkpoint after a few updates, with λ2's floor up",
            0.5,
        )
        st.procs["learner"].kill(signal.SIGKILL)
        st.procs["learner"].popen.wait(10)
        written = sum(int(c.obs.shape[0]) for c in read_all(st.run_dir / "replay"))
        state = (st.run_dir / "checkpoints" / "learner_state.json").read_text()
        ckpt_updates = json.loads(state)["updates"]
        assert written > 0 and ckpt_updates > 0
        ckpt_floor = _ckpt_floor(ckpt)
        assert ckpt_floor >= 0.4

        restarted_at = time.time()
        stop_at = str(ckpt_updates + RESTART_UPDATES)
        st.start(
            "learner", "services.learner", *LEARNER_ARGS, *FLOOR_ARGS, "--max-updates", stop_at
        )

        def restarted() -> object:
            s = w.get("learner", "main")  # stats of a process started after the restart
            if s is not None and s.header.stamp - s.scalars["uptime_s"] >= restarted_at - 0.5:
                return s
            return None

        first = wait_for(restarted, 120, "the restarted learner's stats", 0.1)
        assert first.scalars["updates"] >= ckpt_updates
        assert first.scalars["replay_steps"] >= written
        assert "resumed from checkpoint" in st.procs["learner"].log()
        wait_for(
            lambda: _scalar(w, "learner", "main", "updates") >= ckpt_updates + RESTART_UPDATES,
            120,
            "training to go on",
            0.5,
        )
        # the floor continues from the checkpoint, driven by the rate of the replay read back
        # from disk; a fresh one would be RESTART_UPDATES × 0.5 × rate high
        rate = _scalar(w, "learner", "main", "lambda2/real_rate")
        assert 0.0 < rate < 1.0
        assert RESTART_UPDATES * 0.5 * rate < ckpt_floor
        assert _scalar(w, "learner", "main", "lambda2/floor") >= ckpt_floor
        w.close()
        session.close()


def test_router_restart_everyone_reconnects_and_data_flows(tmp_path: Path) -> None:
    """The router stops and a new one starts on the same port: every service reconnects on its
    own, chunks and features flow again and none was lost. Each step waits on state observed
    over the bus (liveliness tokens, counters in stats stamped after the restart), never on a
    fixed time; a failure carries every process's full log and the last stats seen."""
    everyone = {
        ("repertoire", "main"),
        ("learner", "main"),
        ("collector", "c0"),
        ("collector", "c1"),
    }
    with running_stack(tmp_path) as st:
        _start(st)
        session = st.session()
        w = StatsWatcher(session, st.topics)
        presence = Presence(session, st.topics.alive())

        def alive() -> set[tuple[str, str]]:
            return {p for k in presence.alive() if (p := st.topics.parse_alive(k)) is not None}

        def fresh(service: str, sid: str, since: float) -> pb.Stats | None:
            s = w.get(service, sid)
            return s if s is not None and s.header.stamp > since else None

        try:
            wait_for(lambda: everyone <= alive(), 120, "every service's liveliness token", 0.2)
            wait_for(
                lambda: _scalar(w, "learner", "main", "chunks/c1") > 10, 120, "data flowing", 0.2
            )
            st.procs["router"].stop()
            # our session lost the router: every service's token goes with it
            wait_for(lambda: not everyone & alive(), 60, "the tokens to go with the router")
            restarted = time.time()
            st.start_router()
            wait_for(lambda: everyone <= alive(), 120, "every service back on the new router", 0.2)
            # counters of stats published after the restart, then their growth
            ls0 = wait_for(
                lambda: fresh("learner", "main", restarted),
                60,
                "learner stats after the restart",
                0.1,
            )
            rs0 = wait_for(
                lambda: fresh("repertoire", "main", restarted),
                60,
                "repertoire stats after the restart",
                0.1,
            )
            before = {k: ls0.scalars.get(f"chunks/{k}", 0.0) for k in ("c0", "c1")}
            wait_for(
                lambda: all(
                    _scalar(w, "learner", "main", f"chunks/{k}") > before[k] + 20
                    for k in ("c0", "c1")
                ),
                120,
                "chunks after the restart",
                0.2,
            )
            wait_for(
                lambda: _scalar(w, "repertoire", "main", "commits") > rs0.scalars["commits"],
                120,
                "features after the restart",
                0.2,
            )
            wait_for(
                lambda: _alive_collectors(w) == {"c0", "c1"},
                60,
                "the learner to see both collectors",
                0.2,
            )
            ls = w.get("learner", "main")
            assert ls is not None
            # the collectors held their chunks while the router was down: nothing was lost
            assert ls.scalars["missing/c0"] == 0 and ls.scalars["missing/c1"] == 0, ls.scalars
            dead = [name for name, p in st.procs.items() if not p.alive()]
            assert not dead, f"{dead} died"
        except Exception as e:
            seen = {k: dict(v.scalars) for k, v in w.latest.items()}
            raise AssertionError(
                f"{e}\nalive: {sorted(alive())}\nlast stats: {seen}\n{st.logs(tail=None)}"
            ) from e
        finally:
            presence.undeclare()
            w.close()
            session.close()
