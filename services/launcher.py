"""Start the whole URSA stack on one machine as separate processes (``ursa up`` / ``make run``).

Starts the router, then the repertoire, the learner, N collectors, the dashboard and the HTTP
API, each a separate Python process in its own process group. Prefixes their logs, starts a
service that exits again (``--max-restarts``, as compose's ``restart: unless-stopped``), stops
all of them on Ctrl-C or SIGTERM (SIGTERM, then SIGKILL after a grace period) or when a service
keeps exiting, and leaves no process behind.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Literal

from services.common.metrics import tensorboard_command

_COLORS = ["36", "33", "35", "32", "34", "31", "96", "93", "95", "92"]


RESTART_RESET_S = 600.0
"""Default seconds of running after which a service's restart count is set back to 0."""


@dataclass(frozen=True)
class UpArgs:
    """Start the whole stack on this machine."""

    preset: Literal["auto", "tiny", "point", "small", "cpu", "paper"] = "auto"
    """Config preset of every service. ``auto``: on the A1 ``paper`` with the learner on CUDA
    when torch sees a GPU, else ``cpu`` (the A1's CPU recipe); on the point env ``point`` (the
    point-env learning recipe of the tests)."""
    env: Literal["a1", "point"] = "a1"
    """Environment the collectors run."""
    collectors: int = 2
    """Number of collector processes."""
    run_id: str = "default"
    """Run id (topics and run directory)."""
    runs_dir: str = "runs"
    """Directory of run directories."""
    host: str = "127.0.0.1"
    """Address the router, dashboard and API bind to."""
    router_port: int = 7447
    dashboard_port: int = 8080
    api_port: int = 8000
    evaluator: bool = True
    """Also start an evaluation collector (serves ``POST /evaluate``; feeds no replay)."""
    dashboard: bool = True
    api: bool = True
    wandb: bool = False
    """Also log every service's stats to Weights & Biases (needs the wandb extra)."""
    wandb_mode: Literal["offline", "online"] = "offline"
    """offline: W&B files under the run directory, uploaded later by ``wandb sync``."""
    learner_threads: int = 0
    """torch threads of the learner on a CPU. 0: ``URSA_TORCH_THREADS`` when set; otherwise
    every core while the collectors are paced (``--core.collector.pace wait``, the default:
    simulated collectors wait for the learner and use a fraction of a core), 1 when they run
    free (``-- --core.collector.pace free``), since torch's threads collapse on cores the
    collectors hold (docs/learner.md, "Threads")."""
    grace_s: float = 5.0
    """Seconds between SIGTERM and SIGKILL at shutdown."""
    max_restarts: int = 5
    """Restarts of one service that exits while the stack runs, as compose's ``restart:
    unless-stopped`` (it resumes from the run directory), after 1, 2, 4, ... s; one more exit
    stops the stack with exit code 1, so that a service that cannot start (a bad flag, a config
    it rejects) does not leave the rest running without it. A service that then runs for
    ``restart_reset_s`` has its count set back to 0. 0: the first exit stops it."""
    restart_reset_s: float = RESTART_RESET_S
    """Seconds a restarted service must run before its restart count is set back to 0 (as
    Kubernetes forgets a crash-loop backoff after ten minutes of running)."""
    extra: tuple[str, ...] = ()
    """Extra arguments passed to every service, given after ``--``: ``ursa up --env a1 --
    --core.learner.imag-starts 128``."""


class Child:
    """One service process in its own process group, its output prefixed with its name."""

    def __init__(self, name: str, cmd: list[str], env: dict[str, str], color: str) -> None:
        self.name = name
        self.cmd = cmd
        self.env = env
        self.color = color
        self.restarts = 0
        """How often :func:`supervise` started it again."""
        self.restart_at: float | None = None
        """When (``time.monotonic``) it is started again; None while it runs."""
        self.up_since: float | None = None
        """When :func:`supervise` first saw its current process running; None before that."""
        self._spawn()

    def _spawn(self) -> None:
        self.proc = subprocess.Popen(
            self.cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=self.env,
            start_new_session=True,
            bufsize=1,
            text=True,
        )
        self.ready = threading.Event()
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def respawn(self) -> None:
        """Start the same command again (its old process has exited)."""
        self.restarts += 1
        self.restart_at = None
        self.up_since = None
        self._spawn()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        tty = sys.stdout.isatty()
        prefix = f"\033[{self.color}m{self.name:>12}\033[0m |" if tty else f"{self.name:>12} |"
        out: IO[str] = sys.stdout
        for line in self.proc.stdout:
            if "READY" in line:
                self.ready.set()
            out.write(f"{prefix} {line}" if line.endswith("\n") else f"{prefix} {line}\n")
            out.flush()

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                pass


def supervise(
    children: list[Child],
    max_restarts: int,
    backoff_s: float,
    now: float,
    reset_after_s: float = RESTART_RESET_S,
) -> str | None:
    """One look at the services (not the router): a service that has exited is started again
    ``backoff_s``·2^k seconds later (k: its restarts so far), at most ``max_restarts`` times.
    A service that has then run for ``reset_after_s`` has its count set back to 0, so that a
    rare crash is forgiven while a crash loop still stops the stack.
    Returns why the stack must stop (a service exited once more than that), else None."""
    for c in children:
        code = c.proc.poll()
        if code is None:
            if c.up_since is None:
                c.up_since = now
            elif c.restarts and now - c.up_since >= reset_after_s:
                print(
                    f"{c.name} has run {now - c.up_since:.0f} s since its last restart; "
                    f"its restart count ({c.restarts}) is back to 0",
                    file=sys.stderr,
                    flush=True,
                )
                c.restarts = 0
            continue
        c.up_since = None
        if c.restart_at is None:
            if c.restarts >= max_restarts:
                return (
                    f"{c.name} exited with code {code} after {c.restarts} restarts; "
                    "stopping the stack (its log is above)"
                )
            delay = backoff_s * 2.0**c.restarts
            c.restart_at = now + delay
            print(
                f"{c.name} exited with code {code}; restarting it in {delay:g} s "
                f"(restart {c.restarts + 1} of {max_restarts})",
                file=sys.stderr,
                flush=True,
            )
        elif now >= c.restart_at:
            c.respawn()
    return None


def _wait_port(host: str, port: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.2)
    return False


def resolve_preset(preset: str, env: str, cuda: bool | None = None) -> tuple[str, list[str]]:
    """The preset ``ursa up`` runs and the service arguments it adds: ``auto`` is ``point`` on
    the point env, ``paper`` with the learner on ``cuda`` when a GPU is there (``cuda`` None:
    ask torch), else ``cpu``. Other presets are taken as they are."""
    if preset != "auto":
        return preset, []
    if env == "point":
        return "point", []
    if cuda is None:
        import torch

        cuda = bool(torch.cuda.is_available())
    return ("paper", ["--core.learner.device", "cuda"]) if cuda else ("cpu", [])


def learner_threads(
    requested: int, extra: tuple[str, ...], environ: dict[str, str], cores: int
) -> int:
    """The learner's torch threads under ``ursa up`` (see ``UpArgs.learner_threads``)."""
    if requested > 0:
        return requested
    if environ.get("URSA_TORCH_THREADS"):
        return int(environ["URSA_TORCH_THREADS"])
    args = list(extra)
    free = any(
        a == "--core.collector.pace=free"
        or (a == "--core.collector.pace" and args[i + 1 : i + 2] == ["free"])
        for i, a in enumerate(args)
    )
    return 1 if free else max(1, cores)


def up(args: UpArgs) -> int:
    """Run the stack until Ctrl-C/SIGTERM or until the router dies; returns an exit code."""
    name, implied = resolve_preset(args.preset, args.env)
    args = dataclasses.replace(args, preset=name, extra=(*implied, *args.extra))  # type: ignore[arg-type]
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    endpoint = f"tcp/{args.host}:{args.router_port}"
    env["URSA_ROUTER"] = endpoint
    env["URSA_ROUTER_LISTEN"] = endpoint
    env["URSA_RUN_ID"] = args.run_id
    env["URSA_RUNS_DIR"] = args.runs_dir
    env["URSA_WANDB"] = args.wandb_mode if args.wandb else "off"
    common = ["--preset", args.preset, "--env", args.env, *args.extra]
    py = sys.executable
    children: list[Child] = []
    stopping = threading.Event()

    def start(name: str, module: str, extra: list[str], with_common: bool = True) -> Child:
        cmd = [py, "-m", module, *(common if with_common else []), *extra]
        c = Child(name, cmd, env, _COLORS[len(children) % len(_COLORS)])
        children.append(c)
        return c

    def shutdown(*_: object) -> None:
        stopping.set()

    signal.signal(signal.SIGINT, shutdown)
    signal.signal(signal.SIGTERM, shutdown)

    router = start("router", "services.router", ["--listen", endpoint], with_common=False)
    if not _wait_port(args.host, args.router_port, 20.0):
        print(f"router did not open {endpoint}", file=sys.stderr)
        stopping.set()
    else:
        start("repertoire", "services.repertoire", [])
        threads = learner_threads(args.learner_threads, args.extra, env, os.cpu_count() or 1)
        start("learner", "services.learner", ["--torch-threads", str(threads)])
        for i in range(args.collectors):
            start(
                f"collector-{i}",
                "services.collector",
                ["--collector-id", f"c{i}", "--seed", str(i)],
            )
        if args.evaluator:
            start("evaluator", "services.evaluator", ["--collector-id", "eval"])
        if args.dashboard:
            start(
                "dashboard",
                "services.dashboard",
                ["--host", args.host, "--port", str(args.dashboard_port)],
            )
        if args.api:
            start("api", "services.api", ["--host", args.host, "--port", str(args.api_port)])
        shown = args.host if args.host not in ("0.0.0.0", "") else "localhost"
        print(
            f"\nURSA is up (run {args.run_id}, preset {args.preset}, env {args.env}, "
            f"{args.collectors} collectors)",
            flush=True,
        )
        if args.dashboard:
            print(f"  dashboard: http://{shown}:{args.dashboard_port}", flush=True)
        if args.api:
            print(f"  HTTP API:  http://{shown}:{args.api_port}  (docs: /docs)", flush=True)
        run_dir = Path(args.runs_dir) / args.run_id
        print(f"  router:    {endpoint}\n  run dir:   {run_dir}", flush=True)
        print(f"  metrics:   {tensorboard_command(run_dir)}", flush=True)
        if args.wandb:
            print(
                f"  W&B:       {args.wandb_mode}, files in {run_dir / 'wandb'}"
                + (
                    f" (upload: wandb sync {run_dir / 'wandb'}/offline-run-*)"
                    if args.wandb_mode == "offline"
                    else ""
                ),
                flush=True,
            )
        print("  Ctrl-C stops everything.\n", flush=True)

    code = 0
    while not stopping.is_set():
        if router.proc.poll() is not None:
            print("router exited; stopping the stack", file=sys.stderr, flush=True)
            code = 1
            break
        failed = supervise(
            children[1:], args.max_restarts, 1.0, time.monotonic(), args.restart_reset_s
        )
        if failed is not None:
            print(failed, file=sys.stderr, flush=True)
            code = 1
            break
        stopping.wait(0.5)

    # services first, router last, so that they can say goodbye over the bus
    for c in reversed(children[1:]):
        c.signal(signal.SIGTERM)
    deadline = time.monotonic() + args.grace_s
    for c in children[1:]:
        try:
            c.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    router.signal(signal.SIGTERM)
    try:
        router.proc.wait(timeout=2.0)
    except subprocess.TimeoutExpired:
        pass
    for c in children:
        c.signal(signal.SIGKILL)
        try:
            c.proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            pass
    print("URSA stopped.", flush=True)
    return code
