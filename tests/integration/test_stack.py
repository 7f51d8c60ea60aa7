"""Issue 2's walking skeleton: the launcher's stack moves real data end to end and stops clean."""

from __future__ import annotations

import os
import signal
import time
import uuid
from pathlib import Path

import pytest

from proto.topics import Topics
from services.common.bus import open_session
from services.common.config import BusConfig
from services.stack import StatsWatcher, free_port, launch_up, stop_up, wait_for, wait_port

pytestmark = pytest.mark.slow


def _pids_of_run(run_id: str, module: str = "") -> list[int]:
    """Live processes whose environment carries this run id (and whose command line names
    ``module``)."""
    pids = []
    needle = f"URSA_RUN_ID={run_id}".encode()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            if needle in (d / "environ").read_bytes().split(b"\0"):
                stat = (d / "stat").read_text()
                if module and module.encode() not in (d / "cmdline").read_bytes().split(b"\0"):
                    continue
                if ") Z" not in stat:  # zombies are already gone, only unreaped
                    pids.append(int(d.name))
        except OSError:
            continue
    return pids


def test_launcher_stack_moves_data_and_stops_clean(tmp_path: Path) -> None:
    run_id = f"skel-{uuid.uuid4().hex[:8]}"
    port = free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    launcher = launch_up(run_id, tmp_path / "runs", port, tmp_path / "launcher.log", env)
    try:
        wait_port(port, 30)
        session = open_session(BusConfig(router=f"tcp/127.0.0.1:{port}"))
        watcher = StatsWatcher(session, Topics(run_id))

        def flowing() -> bool:
            ls = watcher.get("learner", "main")
            rs = watcher.get("repertoire", "main")
            if ls is None or rs is None:
                return False
            sc = ls.scalars
            return (
                sc.get("chunks/c0", 0) >= 20
                and sc.get("chunks/c1", 0) >= 20
                and rs.scalars["commits"] > 0
            )

        wait_for(flowing, 90, "chunks from both collectors and features in the repertoire")
        time.sleep(1.0)
        ls = watcher.get("learner", "main")
        assert ls is not None
        for cid in ("c0", "c1"):
            assert ls.scalars[f"gaps/{cid}"] == 0
            assert ls.scalars[f"missing/{cid}"] == 0
            assert ls.scalars[f"duplicates/{cid}"] == 0
            # every chunk the collector published so far arrived in order
            cs = watcher.get("collector", cid)
            assert cs is not None and cs.scalars["chunks"] > 0
        rs = watcher.get("repertoire", "main")
        assert rs is not None and rs.scalars["size"] > 0
        assert len(_pids_of_run(run_id)) >= 5  # launcher's children: router, rep, learner, 2 coll.
        # a service that dies is started again by the launcher and serves again
        (old,) = _pids_of_run(run_id, "services.repertoire")
        os.kill(old, signal.SIGKILL)
        wait_for(
            lambda: _pids_of_run(run_id, "services.repertoire") not in ([], [old]),
            30,
            "the launcher to start the repertoire again",
        )

        def back() -> bool:
            r = watcher.get("repertoire", "main")
            return r is not None and r.scalars["uptime_s"] < 30 and r.scalars["size"] > 0

        wait_for(back, 60, "the restarted repertoire's stats")
        watcher.close()
        session.close()
    finally:
        stop_up(launcher, 20)
    out = (tmp_path / "launcher.log").read_text()
    assert "URSA is up" in out and "URSA stopped." in out, out[-3000:]
    assert "repertoire exited with code -9; restarting it in 1 s (restart 1 of 5)" in out
    wait_for(lambda: not _pids_of_run(run_id), 10, "every process of the run to exit")
    # the learner wrote its replay as MCAP and every service saved its resolved config
    run_dir = tmp_path / "runs" / run_id
    assert list((run_dir / "replay").glob("segment-*.mcap"))
    assert {p.name for p in (run_dir / "config").iterdir()} >= {
        "learner.yaml",
        "repertoire.yaml",
        "collector-c0.yaml",
        "collector-c1.yaml",
    }
