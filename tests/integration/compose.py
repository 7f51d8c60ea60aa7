"""The compose tests' shared part (``test_compose.py``, ``test_compose_faults.py``): the image
fixture, the start-up and removal of one compose project (:func:`compose_stack`), the
:class:`Stack` handle that runs compose commands and reads the HTTP API, and waiting.

Env: URSA_BASE_IMAGE (default ursa-base:bookworm, built here), URSA_TEST_IMAGE (ursa:test),
URSA_TEST_COLLECTOR_ARGS (the collectors' arguments, replacing each test's ``--realtime-factor``).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal, TypeVar

import pytest

ROOT = Path(__file__).resolve().parents[2]
T = TypeVar("T")

INHERITED_UNSET = ("URSA_ARGS", "URSA_LEARNER_ARGS", "COMPOSE_FILE", "COMPOSE_PROJECT_NAME")
"""Variables of the test's own environment that would change the stack: never passed on."""


def log(msg: str) -> None:
    print(f"[compose-test {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def docker_available() -> str | None:
    """None if a Docker engine answers, else why not."""
    if shutil.which("docker") is None:
        return "no docker command on PATH"
    r = subprocess.run(
        ["docker", "info", "--format", "{{.ServerVersion}}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if r.returncode != 0:
        return f"no Docker engine answers `docker info`: {r.stderr.strip()[:200]}"
    return None


def compose_command() -> list[str] | None:
    """``docker compose`` (v2) or ``docker-compose`` (v1.29+), whichever works."""
    for cmd in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(cmd[0]) is None:
            continue
        r = subprocess.run([*cmd, "version"], capture_output=True, text=True, timeout=60)
        if r.returncode == 0:
            return cmd
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))  # the kernel's ephemeral range: high and random
        return int(s.getsockname()[1])


def wait(what: str, fn: Callable[[], T | None], timeout: float, every: float = 2.0) -> T:
    deadline = time.monotonic() + timeout
    last_err: Exception | None = None
    while time.monotonic() < deadline:
        try:
            v = fn()
            if v is not None and v is not False:
                return v
        except (OSError, urllib.error.URLError, ValueError, KeyError) as e:
            last_err = e
        time.sleep(every)
    raise AssertionError(
        f"timed out after {timeout:.0f} s waiting for {what}"
        + (f" (last error: {last_err})" if last_err else "")
    )


class Stack:
    """One compose project: commands, the API, and what the API says."""

    def __init__(
        self,
        compose: list[str],
        project: str,
        env: dict[str, str],
        files: tuple[Path, ...] = (ROOT / "compose.yaml",),
    ) -> None:
        self.compose_cmd = compose
        self.project = project
        self.env = env
        self.files = [a for f in files for a in ("-f", str(f))]
        """``-f FILE`` for compose.yaml and each override."""
        self.api_url = f"http://127.0.0.1:{env['URSA_API_PORT']}"
        self.dashboard_url = f"http://127.0.0.1:{env['URSA_DASHBOARD_PORT']}/"

    def compose(self, *args: str, timeout: float = 300, check: bool = True) -> str:
        cmd = [*self.compose_cmd, "-p", self.project, *self.files, *args]
        r = subprocess.run(
            cmd, cwd=ROOT, env=self.env, capture_output=True, text=True, timeout=timeout
        )
        if check and r.returncode != 0:
            raise AssertionError(
                f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
            )
        if args and args[0] in ("up", "restart"):  # what compose did to each container
            final = (
                "done",
                "up-to-date",
                "Started",
                "Created",
                "Recreated",
                "Running",
                "Restarted",
            )
            lines = dict.fromkeys(
                " ".join(ln.replace("...", " ").split())
                for ln in (r.stdout + r.stderr).splitlines()
                if ln.strip().endswith(final)
            )
            log(f"compose {' '.join(args)}: {'; '.join(lines)}")
        return r.stdout

    def containers(self, service: str) -> list[str]:
        return self.compose("ps", "-q", service).split()

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(self.api_url + path, timeout=10) as r:
            return json.loads(r.read())

    def collectors(self) -> dict[str, dict[str, Any]]:
        return {c["id"]: c for c in self.get("/collectors") if c["alive"]}

    def stats(self, service: str, sid: str = "main") -> dict[str, float] | None:
        """Scalars of a live service's latest stats (None if it is not alive or has none)."""
        for s in self.get("/stats")["services"]:
            if s["service"] == service and s["id"] == sid and s["alive"]:
                return {k: v for k, v in s["scalars"].items() if v is not None}
        return None

    def fresh_stats(self, service: str, since: float) -> dict[str, float] | None:
        """Stats published by a process started after ``since`` (time.time())."""
        st = self.stats(service)
        if st is None or "uptime_s" not in st:
            return None
        return st if st["uptime_s"] < time.time() - since else None

    def dashboard_status(self) -> int:
        with urllib.request.urlopen(self.dashboard_url, timeout=10) as r:
            return int(r.status)

    def save_logs(self, dest: Path) -> None:
        dest.mkdir(parents=True, exist_ok=True)
        r = subprocess.run(
            [
                *self.compose_cmd,
                "-p",
                self.project,
                *self.files,
                "ps",
                "-a",
                "-q",
            ],
            cwd=ROOT,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        for cid in r.stdout.split():
            name = (
                subprocess.run(
                    ["docker", "inspect", "--format", "{{.Name}}", cid],
                    capture_output=True,
                    text=True,
                )
                .stdout.strip()
                .lstrip("/")
            )
            logs = subprocess.run(
                ["docker", "logs", "--timestamps", cid], capture_output=True, text=True
            )
            (dest / f"{name or cid}.log").write_text(logs.stdout + logs.stderr)


@pytest.fixture(scope="session")
def image() -> str:
    """The project image, built from this tree on the base image (``docker/build.sh``), once per
    session for both compose modules (``tests/integration/conftest.py`` provides it). Skips
    where no Docker engine answers; fails where one does but Compose is missing."""
    why = docker_available()
    if why is not None:
        pytest.skip(f"Docker compose test needs a Docker engine: {why}")
    if compose_command() is None:  # an engine without Compose cannot run the deployment: fail
        pytest.fail("a Docker engine is here but neither `docker compose` nor `docker-compose`")
    tag = os.environ.get("URSA_TEST_IMAGE", "ursa:test")
    env = {
        **os.environ,
        "URSA_IMAGE": tag,
        "URSA_BASE_IMAGE": os.environ.get("URSA_BASE_IMAGE", "ursa-base:bookworm"),
    }
    t0 = time.monotonic()
    log(f"building {tag} on {env['URSA_BASE_IMAGE']} (docker/build.sh)")
    r = subprocess.run(
        [str(ROOT / "docker" / "build.sh")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert r.returncode == 0, f"image build failed:\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    log(f"image built in {time.monotonic() - t0:.0f} s: {r.stdout.strip().splitlines()[-1]}")
    return tag


@contextmanager
def compose_stack(
    image: str,
    *,
    project_prefix: str,
    run_id: str,
    realtime_factor: int,
    collector_args: str = "",
    env: dict[str, str] | None = None,
    files: tuple[Path, ...] = (ROOT / "compose.yaml",),
    logs_prefix: str = "compose",
    save_logs: Literal["always", "on_failure"] = "on_failure",
) -> Iterator[Stack]:
    """A compose project named ``<project_prefix><8 hex digits>``, ready for ``up`` (the caller
    brings up what it needs), always removed afterwards (``down -v``).

    Its environment: the test's own (less :data:`INHERITED_UNSET`) with ``image``,
    ``URSA_ENV=point URSA_PRESET=tiny``, ``URSA_RUN_ID=run_id``, high random host ports published
    on 127.0.0.1 only, a 30 s stop grace, collectors at ``--realtime-factor realtime_factor``
    (or ``$URSA_TEST_COLLECTOR_ARGS``) followed by ``collector_args``; then ``env`` on top.
    Every container's log is saved under ``test-artifacts/<logs_prefix>-<project>/``, on
    failure (an exception out of the ``with`` block) or ``always`` (a fixture's teardown does
    not see its tests fail: a fixture wants ``always``).
    """
    compose = compose_command()
    assert compose is not None
    project = f"{project_prefix}{uuid.uuid4().hex[:8]}"
    collectors = os.environ.get("URSA_TEST_COLLECTOR_ARGS", f"--realtime-factor {realtime_factor}")
    if collector_args:
        collectors += f" {collector_args}"
    full_env = {k: v for k, v in os.environ.items() if k not in INHERITED_UNSET}
    full_env.update(
        {
            "URSA_IMAGE": image,
            "URSA_ENV": "point",
            "URSA_PRESET": "tiny",
            "URSA_RUN_ID": run_id,
            "URSA_API_PORT": str(free_port()),
            "URSA_DASHBOARD_PORT": str(free_port()),
            "URSA_ROUTER_PORT": str(free_port()),
            "URSA_PUBLISH_ADDR": "127.0.0.1",
            "URSA_ROUTER_PUBLISH_ADDR": "127.0.0.1",
            "URSA_STOP_GRACE": "30s",
            "URSA_COLLECTOR_ARGS": collectors,
            **(env or {}),
        }
    )
    stack = Stack(compose, project, full_env, files)
    t0 = time.monotonic()
    ok = False
    try:
        yield stack
        ok = True
    finally:
        if save_logs == "always" or not ok:
            dest = ROOT / "test-artifacts" / f"{logs_prefix}-{project}"
            try:
                stack.save_logs(dest)
                log(f"container logs saved under {dest}")
            except Exception as e:  # the test's own failure matters more
                log(f"could not save logs: {e}")
        stack.compose("down", "-v", "--remove-orphans", timeout=600, check=False)
        log(f"stack {project} removed, {time.monotonic() - t0:.0f} s after it was set up")
