"""The run directory (ursa.rundir): the durable atomic write, and the layout every writer uses."""

from __future__ import annotations

import json
import logging
import os
import re
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, BinaryIO
from unittest import mock

import numpy as np
import pytest

from tests.ursa.eval._runs import make_run, small_config
from ursa import rundir
from ursa.eval.loading import load_run
from ursa.rundir import RunDir, atomic_write

ROOT = Path(__file__).resolve().parents[2]


# --- atomic_write ----------------------------------------------------------------------------


def test_writes_text_bytes_and_serializers(tmp_path: Path) -> None:
    p = tmp_path / "a" / "b" / "f.json"  # parents are created
    assert atomic_write(p, "é\n") == p
    assert p.read_bytes() == "é\n".encode()
    atomic_write(p, b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    atomic_write(p, lambda f: np.save(f, np.arange(3)))
    np.testing.assert_array_equal(np.load(p), np.arange(3))
    assert os.listdir(p.parent) == ["f.json"]


@pytest.mark.parametrize("existed", [True, False])
def test_a_failing_serializer_leaves_the_old_content(tmp_path: Path, existed: bool) -> None:
    p = tmp_path / "state.json"
    if existed:
        atomic_write(p, "old")

    def half(f: BinaryIO) -> None:
        f.write(b"new, half of it")
        f.flush()
        raise RuntimeError("serializer failed midway")

    def interrupted(f: BinaryIO) -> None:
        f.write(b"new")
        raise KeyboardInterrupt  # not only Exceptions: a Ctrl-C mid-write too

    with pytest.raises(RuntimeError, match="midway"):
        atomic_write(p, half)
    with pytest.raises(KeyboardInterrupt):
        atomic_write(p, interrupted)
    if existed:
        assert p.read_text() == "old"
        assert os.listdir(tmp_path) == ["state.json"]
    else:
        assert os.listdir(tmp_path) == []


def test_a_failing_rename_leaves_no_temp(tmp_path: Path) -> None:
    p = tmp_path / "x"
    atomic_write(p, "old")
    with (
        mock.patch.object(rundir.os, "replace", side_effect=OSError("disk gone")),
        pytest.raises(OSError, match="disk gone"),
    ):
        atomic_write(p, "new")
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["x"]


def test_fsyncs_the_file_then_the_directory(tmp_path: Path) -> None:
    kinds: list[str] = []
    real = os.fsync

    def spy(fd: int) -> None:
        kinds.append("dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file")
        real(fd)

    with mock.patch.object(rundir.os, "fsync", side_effect=spy):
        atomic_write(tmp_path / "f", "x")
    assert kinds == ["file", "dir"]


def test_mode_is_that_of_open(tmp_path: Path) -> None:
    (tmp_path / "plain").write_text("x")
    atomic_write(tmp_path / "atomic", "x")
    mode = stat.S_IMODE((tmp_path / "plain").stat().st_mode)
    assert stat.S_IMODE((tmp_path / "atomic").stat().st_mode) == mode


_WRITER = """
import sys
from ursa.rundir import atomic_write
path, byte, n, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
for _ in range(n):
    atomic_write(path, bytes([byte]) * size)
"""


def test_concurrent_writers_never_tear(tmp_path: Path) -> None:
    """Three processes and two threads replace one file over and over while it is read: every
    read is one writer's whole payload."""
    p = tmp_path / "shared.bin"
    size, n = 1 << 16, 200
    atomic_write(p, bytes([0]) * size)
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _WRITER, str(p), str(b), str(n), str(size)],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )
        for b in (1, 2, 3)
    ]

    def thread_writer(b: int) -> None:
        for _ in range(n):
            atomic_write(p, bytes([b]) * size)

    threads = [threading.Thread(target=thread_writer, args=(b,)) for b in (4, 5)]
    for t in threads:
        t.start()
    seen: set[int] = set()
    reads = 0
    while any(pr.poll() is None for pr in procs) or any(t.is_alive() for t in threads):
        data = p.read_bytes()
        assert len(data) == size and data == bytes([data[0]]) * size, "torn file"
        seen.add(data[0])
        reads += 1
        time.sleep(0.001)
    for t in threads:
        t.join()
    assert [pr.wait() for pr in procs] == [0, 0, 0]
    data = p.read_bytes()
    assert len(data) == size and data[0] in {1, 2, 3, 4, 5} and data == bytes([data[0]]) * size
    assert reads > 1 and len(seen | {data[0]}) > 1
    assert os.listdir(tmp_path) == ["shared.bin"]  # no writer left a temp file


# --- the layout ------------------------------------------------------------------------------


def test_layout_paths(tmp_path: Path) -> None:
    r = RunDir(str(tmp_path))
    assert r.root == tmp_path
    assert r.config_file("learner") == tmp_path / "config" / "learner.yaml"
    assert r.checkpoint == tmp_path / "checkpoints" / "learner.pt"
    assert r.learner_state == tmp_path / "checkpoints" / "learner_state.json"
    assert r.archive == tmp_path / "repertoire" / "archive.npz"
    assert r.replay == tmp_path / "replay"
    assert r.metrics_file("collector", "c0") == tmp_path / "metrics" / "collector-c0.jsonl"
    assert r.collector_file("c0") == tmp_path / "collectors" / "c0.json"
    assert r.tensorboard == tmp_path / "tensorboard"
    assert r.wandb == tmp_path / "wandb"
    assert r.secrets == tmp_path / "secrets"
    assert r.eval == tmp_path / "eval"
    assert {str(p) for p in rundir.LAYOUT} == {
        "config", "checkpoints", "repertoire", "replay", "metrics", "collectors", "tensorboard",
        "wandb", "secrets", "eval",
    }  # fmt: skip


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file()}


def test_a_serial_run_writes_the_layout(tmp_path: Path) -> None:
    run = make_run(tmp_path, "run", small_config("point"), steps=40, prefill=20)
    r = RunDir(run)
    files = _files(run)
    for p in (r.config_file("serial"), r.checkpoint, r.learner_state, r.archive):
        assert p in files
    assert files - {r.config_file("serial"), r.checkpoint, r.learner_state, r.archive} == {
        r.metrics_file(p.stem.split("-", 1)[0], p.stem.split("-", 1)[1])
        for p in r.metrics.glob("*.jsonl")
    }
    assert {Path(p.name) for p in run.iterdir()} <= set(rundir.LAYOUT)
    assert load_run(run).run_dir == run and load_run(r.checkpoint).run_dir == run


def _fake_runtime(service: str, sid: str, bus: Any, run: Any) -> Any:
    """A ServiceRuntime without a bus (these tests look at files only)."""
    from proto.topics import Topics
    from services.common.bus import DropCounter

    return SimpleNamespace(
        service=service,
        sid=sid,
        run=run,
        topics=Topics(run.run_id),
        log=logging.getLogger(f"{service}/{sid}"),
        drops=DropCounter(),
        session=mock.MagicMock(),
        stop=threading.Event(),
    )


def test_the_services_write_the_layout(tmp_path: Path) -> None:
    """The files each service writes (constructed with a stand-in bus) are the layout's."""
    from services.collector import service as collector
    from services.common.config import RunConfig
    from services.common.metrics import MetricsLog
    from services.learner import service as learner
    from services.repertoire import service as repertoire

    run = RunConfig(run_id="r", root=tmp_path)
    r = RunDir(run.dir)
    cfg = small_config("point")
    with (
        mock.patch.object(learner, "ServiceRuntime", _fake_runtime),
        mock.patch.object(collector, "ServiceRuntime", _fake_runtime),
        mock.patch.object(repertoire, "ServiceRuntime", _fake_runtime),
    ):
        ls = learner.LearnerService(learner.LearnerArgs(core=cfg, run=run, learner_id="main"))
        ls.checkpoint()
        ls.writer.close()
        collector.Collector(collector.CollectorArgs(core=cfg, run=run, collector_id="c0"))
        collector.Collector(collector.CollectorArgs(core=cfg, run=run, collector_id="c0"))
        rs = repertoire.RepertoireService(repertoire.RepertoireArgs(core=cfg, run=run))
        rs.rep.commit(np.zeros(cfg.repertoire.dim))
        rs.save()
    log = MetricsLog(run.dir, run.run_id, "learner", "main")
    log.write(time.time(), {"updates": 1.0}, {})
    log.close()

    files = _files(run.dir)
    expected = {
        r.config_file("learner"),
        r.config_file("collector-c0"),
        r.config_file("repertoire"),
        r.checkpoint,
        r.learner_state,
        r.collector_file("c0"),
        r.archive,
        r.metrics_file("learner", "main"),
    }
    assert expected <= files
    assert json.loads(r.collector_file("c0").read_text())["incarnation"] == 1
    assert json.loads(r.learner_state.read_text())["updates"] == 0
    others = files - expected
    assert others and all(p.is_relative_to(r.tensorboard) for p in others), others
    assert ls.replay_dir == r.replay
    assert {Path(p.name) for p in run.dir.iterdir()} <= set(rundir.LAYOUT)
    assert not [p for p in files if p.name.endswith(rundir.TEMP_SUFFIX)]


def test_no_other_module_spells_the_layout_or_writes_atomically() -> None:
    """Run-directory names and os.replace appear in ursa/rundir.py only (one owner)."""
    layout = "|".join(str(p) for p in rundir.LAYOUT)
    needles = (
        r"os\.replace\(",
        r'\.with_suffix\("[^"]*\.tmp"\)',
        r'"(learner\.pt|learner_state\.json|archive\.npz)"',
        rf'\b(run|run_dir|dir|root|base|p)\)? / "({layout})"',
    )
    hits = [
        f"{f.relative_to(ROOT)}: {m.group(0)}"
        for d in ("ursa", "services")
        for f in sorted((ROOT / d).rglob("*.py"))
        if f.name != "rundir.py"
        for n in needles
        for m in re.finditer(n, f.read_text())
    ]
    assert hits == []


def test_metrics_row_is_the_one_shape_of_a_metrics_line() -> None:
    from ursa.rundir import metrics_row

    row = metrics_row(12.5, "learner", "main", {"updates": 3, "loss": 0.25}, {"phase": "wm"})
    assert row == {
        "t": 12.5,
        "service": "learner",
        "id": "main",
        "scalars": {"updates": 3.0, "loss": 0.25},
        "labels": {"phase": "wm"},
    }
    assert metrics_row(1.0, "collector", "serial", {})["labels"] == {}
