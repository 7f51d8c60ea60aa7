"""Issue 15: faults across hosts in compose, and two routers bridged.

One stack serves every test of this module (brought up once, in file order): ``compose.yaml``
plus ``docker/compose.two-hosts.yaml`` (a second "machine": its own network, its own router
bridged to the main one, one collector behind it) plus a test override that puts the run volume
on a size-limited tmpfs (256 MiB). ``URSA_ENV=point URSA_PRESET=tiny``, two collectors behind
the main router, every collector at 10x real time and unpaced (``--core.collector.pace free``, as
a real robot: data keeps coming whatever the learner does), the learner checkpointing every 2 s;
no evaluator and no dashboard. Authentication and access control are on (the compose default),
across the bridge too.

1. two routers bridged: the collector behind the second router delivers chunks to the learner
   behind the first and receives its weights; a client without credentials is refused there;
2. a collector's container disconnected from its network for 30 s (``docker network
   disconnect``) and reconnected: it drains its backlog; the learner counts no gap, no missing
   chunk;
3. the learner killed (SIGKILL from the host) while it writes a checkpoint (its temporary file
   exists): the restarted learner removes the torn file, loads the previous checkpoint and goes
   on counting updates;
4. the run volume filled up: the learner says so (log and stats), keeps running, the checkpoint
   and every MCAP segment on disk stay valid; once space is back every waiting chunk is written
   (MCAP sequence numbers without holes).

Each test writes a figure (chunks the learner received per collector over time, the fault
shaded, "chunks lost") to ``$URSA_COMPOSE_FIGURES`` (default ``test-artifacts/compose-figures``);
the committed ones in ``docs/figures/`` come from
``URSA_COMPOSE_FIGURES=docs/figures pytest tests/integration/test_compose_faults.py``.
Logs of every container are saved in ``test-artifacts/compose-faults-<project>/``.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.integration.compose import (
    ROOT,
    Stack,
    compose_stack,
    log,
    wait,
)

pytestmark = [pytest.mark.slow, pytest.mark.docker]

RUN_ID = "faults"
PARTITION_S = 30.0
FIGURES = Path(os.environ.get("URSA_COMPOSE_FIGURES", ROOT / "test-artifacts" / "compose-figures"))
CKPT_TMP = re.compile(r"^learner\.pt\..*\.tmp$")


def _docker(*args: str, check: bool = True, timeout: float = 120) -> str:
    r = subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout)
    if check and r.returncode != 0:
        raise AssertionError(f"docker {' '.join(args)} failed: {r.stderr.strip()}")
    return r.stdout.strip()


class Faults:
    """The stack of this module, a stats sampler and what the tests share."""

    def __init__(self, stack: Stack) -> None:
        self.stack = stack
        self.rows: list[tuple[float, dict[str, Any]]] = []
        """(time.time(), {"learner": scalars, "collector/<id>": scalars}) about once a second."""
        self.t0 = time.time()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self.volume = f"{stack.project}_runs"
        self.run_dir = Path(_docker("volume", "inspect", "-f", "{{.Mountpoint}}", self.volume))
        self.run_dir = self.run_dir / RUN_ID

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _sample(self) -> None:
        while not self._stop.is_set():
            try:
                row: dict[str, Any] = {}
                for s in self.stack.get("/stats")["services"]:
                    if not s["alive"]:
                        continue
                    name = s["service"] if s["service"] != "collector" else f"collector/{s['id']}"
                    row[name] = {k: v for k, v in s["scalars"].items() if v is not None}
                    row[name]["labels"] = s.get("labels", {})
                self.rows.append((time.time(), row))
            except Exception:  # the API restarting, a slow answer: the next sample
                pass
            self._stop.wait(1.0)

    def learner(self) -> dict[str, Any] | None:
        for _, row in reversed(self.rows[-3:]):
            if "learner" in row:
                return row["learner"]  # type: ignore[no-any-return]
        return None

    def collector_ids(self, service: str) -> dict[str, str]:
        """{collector id (container host name): container id} of a compose service."""
        out = {}
        for c in self.stack.containers(service):
            out[_docker("inspect", "-f", "{{.Config.Hostname}}", c)] = c
        return out

    def series(self, key: str, service: str = "learner") -> tuple[list[float], list[float]]:
        ts, vs = [], []
        for t, row in self.rows:
            v = row.get(service, {}).get(key)
            if v is not None:
                ts.append(t - self.t0)
                vs.append(float(v))
        return ts, vs

    def at(self, key: str, t: float, service: str = "learner") -> float:
        """The last sampled value of ``key`` at or before ``t`` (time.time())."""
        v = 0.0
        for ts, row in self.rows:
            if ts > t:
                break
            v = float(row.get(service, {}).get(key, v))
        return v

    def lost(self) -> int:
        """Chunks the learner counts as missing (sequence gaps), summed over collectors."""
        st = self.learner() or {}
        return int(st.get("missing_total", 0))

    def figure(
        self,
        name: str,
        title: str,
        windows: list[tuple[float, float, str]],
        lines: list[tuple[float, str]] | None = None,
        extra: str | None = None,
    ) -> Path:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        ids = sorted(
            {
                k.split("/", 1)[1]
                for _, r in self.rows
                for k in r.get("learner", {})
                if k.startswith("chunks/")
            }
        )
        behind2 = set(self.collector_ids("collector2"))
        fig, ax = plt.subplots(figsize=(7, 3.6), dpi=90)
        for cid in ids:
            ts, vs = self.series(f"chunks/{cid}")
            label = f"{cid} (behind router2)" if cid in behind2 else cid
            ax.plot(ts, vs, label=label, lw=1.5)
        for a, b, what in windows:
            ax.axvspan(a - self.t0, b - self.t0, color="tab:red", alpha=0.15, label=what)
        for t, what in lines or []:
            ax.axvline(t - self.t0, color="k", ls="--", lw=1, label=what)
        ax.set_xlabel("time since the stack was up (s)")
        ax.set_ylabel("chunks received by the learner")
        ax.set_title(title, fontsize=10)
        note = f"chunks lost: {self.lost()}" + (f"\n{extra}" if extra else "")
        ax.text(
            0.02, 0.97, note, transform=ax.transAxes, va="top", fontsize=9,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"},
        )  # fmt: skip
        ax.legend(fontsize=7, loc="lower right")
        fig.tight_layout()
        FIGURES.mkdir(parents=True, exist_ok=True)
        path = FIGURES / f"{name}.png"
        fig.savefig(path)
        plt.close(fig)
        log(f"figure {path}")
        return path


OVERRIDE = """\
# test only: the run volume on a size-limited tmpfs, so that a test can fill it
volumes:
  runs:
    driver: local
    driver_opts:
      type: tmpfs
      device: tmpfs
      o: "size=256m,uid=10001,gid=10001,mode=0755"
"""


@pytest.fixture(scope="module")
def faults(image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Faults]:
    override = tmp_path_factory.mktemp("compose") / "tmpfs-runs.yaml"
    override.write_text(OVERRIDE)
    with compose_stack(
        image,
        project_prefix="ursafaults",
        run_id=RUN_ID,
        realtime_factor=10,
        # unpaced (as a real robot): chunks keep coming whatever the learner does
        collector_args="--core.collector.pace free",
        env={"URSA_LEARNER_ARGS": "--checkpoint-every-s 2 --min-replay 500"},
        files=(ROOT / "compose.yaml", ROOT / "docker" / "compose.two-hosts.yaml", override),
        logs_prefix="compose-faults",
        save_logs="always",
    ) as stack:
        t = time.monotonic()
        f: Faults | None = None
        try:
            log(
                f"project {stack.project}: up (2 collectors + 1 behind router2, "
                "no evaluator/dashboard)"
            )
            stack.compose(
                "up", "-d", "--no-build", "--scale", "collector=2", "--scale", "collector2=1",
                "router", "repertoire", "learner", "api", "collector", "router2", "collector2",
            )  # fmt: skip
            wait("the API to answer /health", lambda: stack.get("/health"), 240)
            f = Faults(stack)
            f.start()
            wait(
                "chunks from 3 collectors at the learner",
                lambda: sum(k.startswith("chunks/") for k in (f.learner() or {})) >= 3,
                300,
            )
            log(f"stack up in {time.monotonic() - t:.0f} s")
            yield f
        finally:
            if f is not None:
                f.stop()


def _logs(container: str) -> str:
    r = subprocess.run(["docker", "logs", container], capture_output=True, text=True, timeout=60)
    return r.stdout + r.stderr


# ---- 1. two routers bridged ------------------------------------------------------------------
def test_collector_behind_a_second_router_reaches_the_learner(faults: Faults) -> None:
    t0 = time.time()
    (c2, c2_container), *_ = faults.collector_ids("collector2").items()
    first = wait(
        f"chunks of {c2} (behind router2) at the learner",
        lambda: s if (s := faults.learner()) and s.get(f"chunks/{c2}", 0) > 0 else None,
        120,
    )
    later = wait(
        f"more chunks of {c2}",
        lambda: (
            s
            if (s := faults.learner()) and s[f"chunks/{c2}"] >= first[f"chunks/{c2}"] + 20
            else None
        ),
        120,
    )
    # the other way: the learner's weights reach the collector behind router2 (its stats, which
    # come back across the bridge, carry the policy version it acts with)
    c2_stats = wait(
        f"{c2} acting with learner weights (policy_version > 0)",
        lambda: (
            s if (s := faults.stack.stats("collector", c2)) and s["policy_version"] > 0 else None
        ),
        240,
    )
    # authentication across the bridge: router2 refuses a client without credentials
    probe = (
        "import json, zenoh\n"
        "c = zenoh.Config()\n"
        "c.insert_json5('mode', '\"client\"')\n"
        "c.insert_json5('connect/endpoints', json.dumps(['tcp/router2:7447']))\n"
        "c.insert_json5('scouting/multicast/enabled', 'false')\n"
        "c.insert_json5('connect/timeout_ms', '3000')\n"
        "c.insert_json5('connect/exit_on_failure', 'true')\n"
        "try:\n    zenoh.open(c)\nexcept Exception as e:\n    print('REFUSED', type(e).__name__)\n"
        "else:\n    print('ACCEPTED')\n"
    )
    out = _docker("exec", c2_container, "python", "-c", probe, timeout=60)
    router2 = faults.stack.containers("router2")[0]
    router2_log = _logs(router2)
    log(
        f"{c2} behind router2: {first[f'chunks/{c2}']:.0f} -> {later[f'chunks/{c2}']:.0f} chunks "
        f"at the learner, gaps {later[f'gaps/{c2}']:.0f}, missing {later[f'missing/{c2}']:.0f}; "
        f"its policy version {c2_stats['policy_version']:.0f}; client without credentials: {out}"
    )
    assert "bridged to tcp/router:7447" in router2_log and "authentication on" in router2_log, (
        router2_log[-2000:]
    )
    assert out.strip().startswith("REFUSED"), out
    assert later[f"missing/{c2}"] == 0 and later[f"gaps/{c2}"] == 0, later
    faults.figure(
        "compose_two_routers",
        "two routers bridged: a collector behind router2 feeds the learner behind router",
        [],
        [(t0, "test start")],
    )


# ---- 2. a collector cut off its network for 30 s -------------------------------------------
def test_partitioned_collector_drains_its_backlog_without_loss(faults: Faults) -> None:
    ids = faults.collector_ids("collector")
    cid, container = sorted(ids.items())[0]
    network = f"{faults.stack.project}_default"
    before = wait("learner stats", faults.learner, 30)
    n0 = before[f"chunks/{cid}"]
    t_cut = time.time()
    _docker("network", "disconnect", network, container)
    log(f"collector {cid} disconnected from {network} ({n0:.0f} chunks received so far)")
    try:
        time.sleep(PARTITION_S)
    finally:
        _docker("network", "connect", network, container)
    t_back = time.time()
    log(f"collector {cid} reconnected after {t_back - t_cut:.0f} s")
    # while cut off, it went on collecting into its backlog (its own stats say how much once
    # they can reach us); drained when the learner has every chunk it numbered
    produced = wait(
        f"stats of {cid} after reconnecting, counting the chunks it made meanwhile",
        lambda: (
            s if (s := faults.stack.stats("collector", cid)) and s["chunks"] > n0 + 10 else None
        ),
        120,
    )
    drained = wait(
        f"the learner to receive {cid}'s backlog ({produced['chunks']:.0f} chunks numbered)",
        lambda: (
            s if (s := faults.learner()) and s[f"next_seq/{cid}"] >= produced["chunks"] else None
        ),
        120,
    )
    t_drained = time.time()
    # what it had put just before the cut may still be ingested for a few seconds (the lease
    # lets a dead link look alive for up to 10 s); in the partition's second half, nothing
    n_half = faults.at(f"chunks/{cid}", t_cut + PARTITION_S / 2)
    n_back = faults.at(f"chunks/{cid}", t_back)
    got_during = n_back - n_half
    backlog = drained[f"chunks/{cid}"] - n_back
    log(
        f"{cid}: {n_half - n0:.0f} chunks arrived in the partition's first half, "
        f"{got_during:.0f} in its second, {backlog:.0f} after it "
        f"(drained {t_drained - t_back:.0f} s after reconnecting); gaps "
        f"{drained[f'gaps/{cid}']:.0f}, missing {drained[f'missing/{cid}']:.0f}, duplicates "
        f"{drained[f'duplicates/{cid}']:.0f} (resent, dropped by seq); missing_total "
        f"{drained['missing_total']:.0f}"
    )
    faults.figure(
        "compose_partition",
        f"collector {cid} disconnected from its network for {PARTITION_S:.0f} s",
        [(t_cut, t_back, "network disconnected")],
        [(t_drained, "backlog drained")],
        extra=f"backlog delivered after reconnect: {backlog:.0f} chunks",
    )
    assert got_during == 0, f"{got_during} chunks arrived from a disconnected container"
    assert backlog > 10, f"only {backlog} chunks came after reconnecting: no backlog drained"
    assert drained[f"gaps/{cid}"] == 0 and drained[f"missing/{cid}"] == 0, drained
    assert drained["missing_total"] == 0, drained


# ---- 3. the learner killed while it writes a checkpoint ------------------------------------
def _kill_during_checkpoint(ckpt_dir: Path, pid: int, within_s: float) -> str | None:
    """Busy-watch the checkpoint directory; SIGKILL ``pid`` as soon as a checkpoint temporary
    file appears. Returns its name if it was still there after the kill (killed mid-write)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            names = os.listdir(ckpt_dir)
        except FileNotFoundError:
            names = []
        tmp = next((n for n in names if CKPT_TMP.match(n)), None)
        if tmp is not None:
            os.kill(pid, signal.SIGKILL)
            time.sleep(0.2)
            return tmp if (ckpt_dir / tmp).exists() else None
    raise AssertionError(f"no checkpoint write seen in {ckpt_dir} within {within_s:.0f} s")


def _checkpoint_updates(path: Path) -> int:
    import torch

    state = torch.load(path, map_location="cpu", weights_only=True)
    return int(state["updates"])


def test_learner_killed_during_checkpoint_write_resumes_from_previous(faults: Faults) -> None:
    ckpt_dir = faults.run_dir / "checkpoints"
    wait(
        "a checkpoint of a training learner",
        lambda: (
            (s := faults.learner())
            and s.get("updates", 0) > 0
            and (ckpt_dir / "learner.pt").exists()
        ),
        240,
    )
    container = faults.stack.containers("learner")[0]
    torn = None
    for attempt in range(3):
        pid = int(_docker("inspect", "-f", "{{.State.Pid}}", container))
        before = faults.learner() or {}
        # a checkpoint's temporary file lives for milliseconds: on a loaded machine (the suite's
        # background trainings) a 30 s watch saw none of ~15 writes (fresh clone, 2026-12-03)
        torn = _kill_during_checkpoint(ckpt_dir, pid, 120)
        t_kill = time.time()
        if torn is not None:
            break
        log(f"attempt {attempt}: the kill landed just after a checkpoint write; again")
        wait(
            "the learner back (restart policy)",
            lambda t=t_kill: faults.stack.fresh_stats("learner", t),  # type: ignore[misc]
            240,
        )
    assert torn is not None, "never killed the learner inside a checkpoint write"
    prev = _checkpoint_updates(ckpt_dir / "learner.pt")  # the previous, complete checkpoint
    log(
        f"learner SIGKILLed inside a checkpoint write ({torn} left behind) at "
        f"{before.get('updates', 0):.0f} updates; learner.pt on disk holds {prev} updates"
    )
    # the restart policy brings it back (a SIGKILL from outside docker is a crash to docker)
    post = wait(
        "stats from the restarted learner", lambda: faults.stack.fresh_stats("learner", t_kill), 240
    )
    t_back = time.time()
    more = wait(
        "the restarted learner to go on training",
        lambda: s if (s := faults.learner()) and s["updates"] > post["updates"] + 2 else None,
        240,
    )
    logs = _logs(container)
    rows = (faults.run_dir / "metrics" / "learner-main.jsonl").read_text().splitlines()
    removed = json.loads(rows[-1])["scalars"].get("checkpoint_tmp_removed")
    log(f"metrics row: checkpoint_tmp_removed {removed}; post {post}")
    log(
        f"restarted learner: removed {post['checkpoint_tmp_removed']:.0f} torn file(s), "
        f"starts at {post['updates']:.0f} updates, then {more['updates']:.0f}; "
        f"missing_total {more['missing_total']:.0f}"
    )
    faults.figure(
        "compose_kill_checkpoint",
        "learner SIGKILLed inside a checkpoint write, restarted by its policy",
        [(t_kill, t_back, "learner down")],
        extra=f"checkpoint on disk: {prev} updates; resumed at {post['updates']:.0f}, "
        f"then {more['updates']:.0f}",
    )
    assert not (ckpt_dir / torn).exists(), "the restarted learner left the torn checkpoint file"
    assert post["checkpoint_tmp_removed"] >= 1, post
    assert f"resumed from checkpoint at {prev} updates" in logs, logs[-3000:]
    # no bound from `before`: it is read before the watch for a write (up to 120 s of training),
    # and checkpoints completed during the watch hold more updates (CI 2026-12-06: 176 on disk,
    # 174 in the stats before the watch). What matters: learner.pt loads (a complete file, read
    # above), the restart resumed from it (the log line) and went on from there.
    assert post["updates"] >= prev, (prev, before, post)
    assert more["updates"] > post["updates"] >= prev > 0
    assert more["missing_total"] == 0, more


# ---- 4. the run volume full ----------------------------------------------------------------
def _mcap_check(path: Path) -> list[tuple[str, int, int]]:
    """(collector, incarnation, seq) of every chunk in a segment; asserts the file ends at a
    record boundary (a segment cut by a crash or a full disk may lack its footer, never hold a
    torn record) and that the mcap reader checks every CRC."""
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Footer, Message
    from mcap.stream_reader import StreamReader

    from proto import ursa_pb2 as pb

    size = path.stat().st_size
    out = []
    channels: dict[int, str] = {}
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, validate_crcs=True)
        boundary = 0
        footer = False
        try:
            for rec in reader.records:
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message) and channels[rec.channel_id].startswith(
                    "/transitions/"
                ):
                    m = pb.TransitionChunk()
                    m.ParseFromString(rec.data)
                    out.append((m.collector_id, int(m.incarnation), int(m.seq)))
                footer = footer or isinstance(rec, Footer)
                boundary = reader._stream.count
        except EndOfFile:
            pass
    if not footer:
        assert boundary == size, (
            f"{path.name}: torn record ({size - boundary} bytes after the last)"
        )
    return out


def test_full_run_volume_gives_a_clear_error_and_no_corrupt_files(faults: Faults) -> None:
    import shutil

    learner = faults.stack.containers("learner")[0]
    ckpt = faults.run_dir / "checkpoints" / "learner.pt"
    filler = faults.run_dir.parent / "filler"
    free = shutil.disk_usage(faults.run_dir).free
    t_full = time.time()
    with open(filler, "wb") as f:  # take every free byte of the tmpfs
        try:
            while True:
                f.write(b"\0" * (1 << 20))
        except OSError:
            pass
    log(f"run volume filled ({free / 2**20:.0f} MiB were free)")
    try:
        full = wait(
            "the learner to report the full volume (replay and checkpoint)",
            lambda: (
                s
                if (s := faults.learner())
                and s.get("replay_write_errors", 0) > 0
                and s.get("checkpoint_errors", 0) > 0
                and s.get("storage_ok") == 0
                else None
            ),
            90,
        )
        time.sleep(5)  # chunks keep arriving and wait in memory
        held = faults.learner() or {}
        # on disk meanwhile: the checkpoint loads, no temporary file, every segment readable
        updates_on_disk = _checkpoint_updates(ckpt)
        tmp = [p.name for p in ckpt.parent.iterdir() if p.name.endswith(".tmp")]
        segments = sorted((faults.run_dir / "replay").glob("segment-*.mcap"))
        on_disk = [c for seg in segments for c in _mcap_check(seg)]
    finally:
        filler.unlink()
        t_freed = time.time()
    log(
        f"full: replay_write_errors {held['replay_write_errors']:.0f}, checkpoint_errors "
        f"{held['checkpoint_errors']:.0f}, chunks waiting {held['replay_unpersisted']:.0f}; "
        f"label: {held['labels'].get('storage_error', '')!r}; checkpoint on disk loads "
        f"({updates_on_disk} updates), {len(segments)} segments with {len(on_disk)} chunks read"
    )
    ok = wait(
        "the learner to write again (storage_ok, nothing waiting, a new checkpoint)",
        lambda: (
            s
            if (s := faults.learner())
            and s.get("storage_ok") == 1
            and s.get("replay_unpersisted") == 0
            and ckpt.stat().st_mtime > t_freed
            else None
        ),
        60,
    )
    t_ok = time.time()
    logs = _logs(learner)
    assert "is full (ENOSPC: No space left on device) writing the replay" in logs, logs[-3000:]
    assert "is full (ENOSPC: No space left on device) writing the checkpoint" in logs
    assert "the previous checkpoint is kept" in logs
    assert held["uptime_s"] > full["uptime_s"], "the learner restarted while the disk was full"
    assert held["ingested_steps"] > full["ingested_steps"] - 1
    assert not tmp, f"temporary files left in checkpoints/: {tmp}"
    # stop the learner (SIGTERM: it writes what it holds) and read every segment back: each
    # collector's chunks numbered without a hole
    stopped_at = faults.learner() or ok
    faults.stack.compose("stop", "learner", timeout=120)
    chunks = [
        c
        for seg in sorted((faults.run_dir / "replay").glob("segment-*.mcap"))
        for c in _mcap_check(seg)
    ]
    holes = 0
    by_stream: dict[tuple[str, int], list[int]] = {}
    for cid, inc, seq in chunks:
        by_stream.setdefault((cid, inc), []).append(seq)
    for seqs in by_stream.values():
        s = sorted(set(seqs))
        holes += (s[-1] - s[0] + 1) - len(s)
    received = sum(v for k, v in stopped_at.items() if k.startswith("chunks/"))
    log(
        f"after the stop: {len(chunks)} chunks in {len(by_stream)} streams on disk, "
        f"{holes} holes in their sequence numbers; the learner had received {received:.0f}"
    )
    faults.figure(
        "compose_full_volume",
        "run volume (tmpfs) full: replay and checkpoint writes refused, then space freed",
        [(t_full, t_freed, "volume full")],
        [(t_ok, "all waiting chunks written")],
        extra=f"write errors: replay {held['replay_write_errors']:.0f}, checkpoint "
        f"{held['checkpoint_errors']:.0f}; on disk after stop: {len(chunks)} chunks, "
        f"{holes} seq holes",
    )
    assert holes == 0, by_stream
    assert len(chunks) >= received, (len(chunks), received)
    assert "is full" in held["labels"].get("storage_error", ""), held["labels"]
