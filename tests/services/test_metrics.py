"""Stats sinks of every service (services/common/metrics.py), read back with each tool's reader:
TensorBoard's EventAccumulator, W&B's own record protobufs, the JSONL rows."""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from services.common.metrics import MetricsLog, tensorboard_command, tensorboard_dir


def _scalars(run_dir: Path) -> dict[str, dict[str, list[tuple[int, float]]]]:
    """{TensorBoard run: {tag: [(step, value)]}} of every event file under run_dir/tensorboard."""
    out: dict[str, dict[str, list[tuple[int, float]]]] = {}
    for d in sorted(p for p in tensorboard_dir(run_dir).iterdir() if p.is_dir()):
        acc = EventAccumulator(str(d))
        acc.Reload()
        out[d.name] = {
            t: [(e.step, e.value) for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]
        }
    return out


def test_learner_rows_reach_tensorboard_at_updates_and_env_steps(tmp_path: Path) -> None:
    m = MetricsLog(tmp_path, "r1", "learner", "main")
    rows = [
        {"updates": 0, "ingested_steps": 50, "wm/loss": 3.0},
        {"updates": 40, "ingested_steps": 120, "wm/loss": 2.5, "chunks/c0": 7},
        {"updates": 95, "ingested_steps": 260, "wm/loss": 1.25, "chunks/c0": 9},
    ]
    for i, r in enumerate(rows):
        m.write(1000.0 + i, {k: float(v) for k, v in r.items()}, {"mode": "ursa"})
    m.close()
    got = _scalars(tmp_path)
    assert set(got) == {"learner-main", "learner-main.env_steps"}
    assert got["learner-main"]["wm/loss"] == [(0, 3.0), (40, 2.5), (95, 1.25)]
    assert got["learner-main.env_steps"]["wm/loss"] == [(50, 3.0), (120, 2.5), (260, 1.25)]
    # a scalar missing from a row is missing at that step, not carried over
    assert got["learner-main"]["chunks/c0"] == [(40, 7.0), (95, 9.0)]
    # wall times are the rows' own
    acc = EventAccumulator(str(tensorboard_dir(tmp_path) / "learner-main"))
    acc.Reload()
    assert [e.wall_time for e in acc.Scalars("wm/loss")] == [1000.0, 1001.0, 1002.0]
    lines = (tmp_path / "metrics" / "learner-main.jsonl").read_text().splitlines()
    assert [json.loads(x)["scalars"]["wm/loss"] for x in lines] == [3.0, 2.5, 1.25]
    assert tensorboard_command(tmp_path).endswith(f"--logdir {tmp_path / 'tensorboard'}")


def test_step_axis_per_service(tmp_path: Path) -> None:
    for service, sid, key in (
        ("collector", "c3", "steps"),
        ("repertoire", "main", "commits"),
        ("dashboard", "main", None),
    ):
        m = MetricsLog(tmp_path, "r1", service, sid)
        for i, step in enumerate((200, 450, 700)):
            sc = {"x": float(i)} | ({key: float(step)} if key else {})
            m.write(float(i), sc, {})
        m.close()
    got = _scalars(tmp_path)
    assert got["collector-c3"]["x"] == [(200, 0.0), (450, 1.0), (700, 2.0)]
    assert got["repertoire-main"]["x"] == [(200, 0.0), (450, 1.0), (700, 2.0)]
    assert got["dashboard-main"]["x"] == [(1, 0.0), (2, 1.0), (3, 2.0)]  # its row count


def test_a_failing_sink_is_dropped_and_the_others_go_on(tmp_path: Path) -> None:
    (tmp_path / "metrics").write_text("not a directory")  # the JSONL sink cannot open its file
    m = MetricsLog(tmp_path, "r1", "collector", "c0")
    m.write(1.0, {"steps": 10.0, "y": 1.0}, {})
    m.write(2.0, {"steps": 20.0, "y": 2.0}, {})
    assert [type(s).__name__ for s in m.sinks] == ["TensorBoardSink"]
    m.close()
    assert _scalars(tmp_path)["collector-c0"]["y"] == [(10, 1.0), (20, 2.0)]


def _wandb_records(path: Path) -> Iterator[object]:
    """The records of a W&B run file (``.wandb``): a 7-byte ``:W&B`` header, then LevelDB log
    blocks of 32 KiB, whose records (FULL, or FIRST/MIDDLE/LAST pieces) are ``Record``
    protobufs."""
    from wandb.proto import wandb_internal_pb2 as wpb

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    pos, buf = 7, b""
    while pos + 7 <= len(data):
        left = 32768 - pos % 32768
        if left < 7:
            pos += left
            continue
        _crc, n, kind = struct.unpack("<IHB", data[pos : pos + 7])
        chunk, pos = data[pos + 7 : pos + 7 + n], pos + 7 + n
        if kind == 0:
            continue
        buf = chunk if kind in (1, 2) else buf + chunk
        if kind in (1, 4):
            r = wpb.Record()  # type: ignore[attr-defined]
            r.ParseFromString(buf)
            yield r


def test_wandb_offline_run_holds_the_rows(tmp_path: Path) -> None:
    pytest.importorskip("wandb")  # the wandb extra (the dev extra includes it)
    m = MetricsLog(tmp_path, "run-7", "learner", "main", wandb_mode="offline")
    assert [type(s).__name__ for s in m.sinks][-1] == "WandbSink"
    m.write(1.0, {"updates": 10.0, "ingested_steps": 100.0, "wm/loss": 2.0}, {})
    m.write(2.0, {"updates": 30.0, "ingested_steps": 250.0, "wm/loss": 1.5}, {})
    m.close()

    def read() -> tuple[list[dict[str, Any]], list[Any]]:
        (f,) = (tmp_path / "wandb").glob("offline-run-*/run-*.wandb")
        history, runs = [], []
        for r in _wandb_records(f):
            kind = r.WhichOneof("record_type")  # type: ignore[attr-defined]
            if kind == "history":
                items = r.history.item  # type: ignore[attr-defined]
                history.append(
                    {i.key or ".".join(i.nested_key): json.loads(i.value_json) for i in items}
                )
            elif kind == "run":
                runs.append(r.run)  # type: ignore[attr-defined]
        return history, runs

    # W&B's service process writes the offline file on its own schedule: under load the
    # history records land a moment after finish() returns
    deadline = time.monotonic() + 60.0
    history, runs = read()
    while len(history) < 2 and time.monotonic() < deadline:
        time.sleep(0.5)
        history, runs = read()
    assert [(h["updates"], h["ingested_steps"], h["wm/loss"]) for h in history] == [
        (10, 100, 2.0),
        (30, 250, 1.5),
    ]
    assert runs and runs[0].run_group == "run-7" and runs[0].display_name == "learner-main"


def test_jsonl_sink_writes_the_run_directorys_metrics_row(tmp_path: Path) -> None:
    from services.common.metrics import JsonlSink
    from ursa.rundir import RunDir, metrics_row

    sink = JsonlSink(tmp_path, "learner", "main")
    sink.write(12.5, {"updates": 3, "loss": 0.25}, {"phase": "wm"})
    sink.close()
    path = RunDir(tmp_path).metrics_file("learner", "main")
    row = metrics_row(12.5, "learner", "main", {"updates": 3, "loss": 0.25}, {"phase": "wm"})
    assert [json.loads(x) for x in path.read_text().splitlines()] == [row]
