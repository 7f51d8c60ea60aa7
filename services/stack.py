"""A stack of real URSA processes over a real Zenoh router on loopback: the harness of the
tests (tests/services, tests/integration) and of the benchmarks that run services."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.common.bus import open_session
from services.common.config import BusConfig

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_port(port: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port}")


class Proc:
    """A service subprocess in its own process group, logging to a file."""

    def __init__(
        self, name: str, args: list[str], log_dir: Path, env: dict[str, str] | None = None
    ) -> None:
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "ab")  # noqa: SIM115 - closed in stop()
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.popen = subprocess.Popen(
            [sys.executable, *args],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            env=full_env,
            start_new_session=True,
        )

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.alive():
            try:
                os.killpg(self.popen.pid, sig)
            except ProcessLookupError:
                pass

    def stop(self, timeout: float = 10.0) -> int | None:
        self.kill(signal.SIGTERM)
        try:
            self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill(signal.SIGKILL)
            self.popen.wait(timeout=5)
        self._log.close()
        return self.popen.returncode


class Stack:
    """Starts services against one router and run directory; stops them all at the end."""

    def __init__(self, tmp: Path, run_id: str = "test", preset: str = "tiny", env: str = "point"):
        self.tmp = tmp
        self.run_id = run_id
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.bus = BusConfig(router=self.endpoint, listen=self.endpoint, connect_timeout_s=20.0)
        self.runs = tmp / "runs"
        self.preset = preset
        self.env = env
        self.procs: dict[str, Proc] = {}
        self.topics = Topics(run_id)
        (tmp / "logs").mkdir(parents=True, exist_ok=True)

    @property
    def run_dir(self) -> Path:
        return self.runs / self.run_id

    def common(self) -> list[str]:
        return [
            "--preset",
            self.preset,
            "--env",
            self.env,
            "--bus.router",
            self.endpoint,
            "--run.run-id",
            self.run_id,
            "--run.root",
            str(self.runs),
        ]

    def start_router(self) -> Proc:
        p = Proc("router", ["-m", "services.router", "--listen", self.endpoint], self.tmp / "logs")
        self.procs["router"] = p
        wait_port(self.port)
        return p

    def start(self, name: str, module: str, *extra: str) -> Proc:
        p = Proc(name, ["-m", module, *self.common(), *extra], self.tmp / "logs")
        self.procs[name] = p
        return p

    def start_collectors(self, n: int, *flags: str) -> list[Proc]:
        """Collectors ``c0`` … ``c{n-1}``, collector i seeded i, each with ``flags``."""
        return [
            self.start(
                f"c{i}", "services.collector", *flags, "--collector-id", f"c{i}", "--seed", str(i)
            )
            for i in range(n)
        ]

    def start_training(
        self,
        *flags: str,
        collectors: int = 2,
        learner: Sequence[str] = (),
        collector: Sequence[str] = (),
    ) -> None:
        """What trains: the router, the repertoire, the learner and ``collectors`` collectors,
        every service with ``flags``; ``learner`` and ``collector`` flags for those alone."""
        self.start_router()
        self.start("repertoire", "services.repertoire", *flags)
        self.start("learner", "services.learner", *flags, *learner)
        self.start_collectors(collectors, *flags, *collector)

    def session(self) -> zenoh.Session:
        return open_session(self.bus)

    def stop_all(self) -> None:
        for name, p in reversed(list(self.procs.items())):
            if name != "router":
                p.stop()
        if "router" in self.procs:
            self.procs["router"].stop()

    def logs(self, tail: int | None = 4000) -> str:
        """Every process's log (its last ``tail`` characters; None: all of it)."""
        return "\n".join(
            f"===== {n} ({p.log_path})\n{p.log()[-tail:] if tail else p.log()}"
            for n, p in self.procs.items()
        )


class StatsWatcher:
    """Keeps the latest Stats of every (service, id) seen on the bus."""

    def __init__(self, session: zenoh.Session, topics: Topics) -> None:
        self.latest: dict[tuple[str, str], pb.Stats] = {}

        def on(sample: zenoh.Sample) -> None:
            try:
                msg = codec.decode(pb.Stats, sample.payload.to_bytes())
            except codec.BadMessage:
                return
            self.latest[(msg.service, msg.id)] = msg

        self._sub = session.declare_subscriber(topics.all_stats, on)

    def get(self, service: str, sid: str) -> pb.Stats | None:
        return self.latest.get((service, sid))

    def close(self) -> None:
        self._sub.undeclare()


def launch_up(
    run_id: str, runs_dir: Path, port: int, log: Path, env: dict[str, str]
) -> subprocess.Popen[bytes]:
    """``ursa up`` of the point env's ``tiny`` preset with two collectors and no dashboard, API
    or evaluator, as a process in its own session writing to ``log``."""
    out = open(log, "wb")  # noqa: SIM115 - the child holds it; closed here once it is handed over
    try:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.cli",
                "up",
                "--env",
                "point",
                "--preset",
                "tiny",
                "--collectors",
                "2",
                "--run-id",
                run_id,
                "--runs-dir",
                str(runs_dir),
                "--router-port",
                str(port),
                "--no-dashboard",
                "--no-api",
                "--no-evaluator",
            ],
            cwd=ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    finally:
        out.close()


def stop_up(launcher: subprocess.Popen[bytes], timeout: float) -> None:
    """SIGTERM to ``ursa up`` and wait for it; SIGKILL to its whole group after ``timeout``."""
    launcher.send_signal(signal.SIGTERM)
    try:
        launcher.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(launcher.pid, signal.SIGKILL)
        launcher.wait(timeout=10)


def wait_for(pred: Callable[[], Any], timeout: float, what: str, every: float = 0.2) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(every)
    raise TimeoutError(f"timed out after {timeout:.0f}s waiting for {what}")


@contextmanager
def running_stack(tmp: Path, **kw: Any) -> Iterator[Stack]:
    st = Stack(tmp, **kw)
    try:
        yield st
    finally:
        st.stop_all()
