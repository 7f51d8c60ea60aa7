"""Issue 8: the compose deployment, built from this tree, survives the faults a cluster sees.

From the working tree: a local base image (docker/build-base.sh, mmdebstrap; skipped when the tag
exists), the project image on it (docker/build.sh: wheelhouse + cached dependency layer), then
``compose.yaml`` under a unique project name with high random host ports, ``URSA_ENV=point
URSA_PRESET=tiny`` and 3 collectors. Checked through the HTTP API and the dashboard's port:

1. 3 collectors alive, the learner's replay grows, the dashboard answers 200;
2. one collector SIGKILLed: the other two go on and the API lists two; then
   ``--scale collector=4``: four;
3. the learner container restarted: it resumes from the volume (policy version and replay size do
   not go back);
4. ``down`` (volume kept) then ``up``: the repertoire and the replay are restored, not empty.

The stack is always removed (``down -v``); on failure every container's log is saved under
``test-artifacts/compose-<project>/``. Skips only where no Docker engine answers (fails where one
does but Compose is missing).
Env: URSA_BASE_IMAGE (default ursa-base:bookworm, built here), URSA_TEST_IMAGE (ursa:test),
URSA_TEST_COLLECTOR_ARGS (default ``--realtime-factor 25``: collectors throttled to 25x real time).
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
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest

ROOT = Path(__file__).resolve().parents[2]
T = TypeVar("T")

pytestmark = [pytest.mark.slow, pytest.mark.docker]


def _log(msg: str) -> None:
    print(f"[compose-test {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def _docker_available() -> str | None:
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


def _compose_command() -> list[str] | None:
    """``docker compose`` (v2) or ``docker-compose`` (v1.29+), whichever works."""
    for cmd in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(cmd[0]) is None:
            continue
        r = subprocess.run([*cmd, "version"], capture_output=True, text=True, timeout=60)
        if r.returncode == 0:
            return cmd
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))  # the kernel's ephemeral range: high and random
        return int(s.getsockname()[1])


def _wait(what: str, fn: Callable[[], T | None], timeout: float, every: float = 2.0) -> T:
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
            _log(f"compose {' '.join(args)}: {'; '.join(lines)}")
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


@pytest.fixture(scope="module")
def image() -> str:
    why = _docker_available()
    if why is not None:
        pytest.skip(f"Docker compose test needs a Docker engine: {why}")
    if _compose_command() is None:  # an engine without Compose cannot run the deployment: fail
        pytest.fail("a Docker engine is here but neither `docker compose` nor `docker-compose`")
    tag = os.environ.get("URSA_TEST_IMAGE", "ursa:test")
    env = {
        **os.environ,
        "URSA_IMAGE": tag,
        "URSA_BASE_IMAGE": os.environ.get("URSA_BASE_IMAGE", "ursa-base:bookworm"),
    }
    t0 = time.monotonic()
    _log(f"building {tag} on {env['URSA_BASE_IMAGE']} (docker/build.sh)")
    r = subprocess.run(
        [str(ROOT / "docker" / "build.sh")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert r.returncode == 0, f"image build failed:\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    _log(f"image built in {time.monotonic() - t0:.0f} s: {r.stdout.strip().splitlines()[-1]}")
    return tag


@pytest.mark.timeout(3600)
def test_compose_stack_scales_and_survives_faults(image: str) -> None:
    compose = _compose_command()
    assert compose is not None
    project = f"ursatest{uuid.uuid4().hex[:8]}"
    env = {
        **os.environ,
        "URSA_IMAGE": image,
        "URSA_ENV": "point",
        "URSA_PRESET": "tiny",
        "URSA_RUN_ID": "compose-test",
        "URSA_API_PORT": str(_free_port()),
        "URSA_DASHBOARD_PORT": str(_free_port()),
        "URSA_ROUTER_PORT": str(_free_port()),
        "URSA_PUBLISH_ADDR": "127.0.0.1",
        "URSA_ROUTER_PUBLISH_ADDR": "127.0.0.1",
        "URSA_STOP_GRACE": "30s",
        # Unthrottled point-mass collectors outrun the repertoire and starve a small machine
        # (9 containers on 2 cores); 25x real time still fills the replay by hundreds of steps/s.
        "URSA_COLLECTOR_ARGS": os.environ.get("URSA_TEST_COLLECTOR_ARGS", "--realtime-factor 25"),
    }
    for k in ("URSA_ARGS", "URSA_LEARNER_ARGS", "COMPOSE_FILE", "COMPOSE_PROJECT_NAME"):
        env.pop(k, None)
    stack = Stack(compose, project, env)
    t_start = time.monotonic()
    ok = False
    try:
        # --- 1. up with 3 collectors --------------------------------------------------------
        _log(
            f"project {project}: up --scale collector=3 (API :{env['URSA_API_PORT']}, "
            f"dashboard :{env['URSA_DASHBOARD_PORT']})"
        )
        stack.compose("up", "-d", "--no-build", "--scale", "collector=3")
        _wait("the API to answer /health", lambda: stack.get("/health"), 240)
        three = _wait(
            "3 live collectors in GET /collectors",
            lambda: c if len(c := stack.collectors()) == 3 else None,
            240,
        )
        _log(f"3 collectors alive: {sorted(three)}")
        first = _wait(
            "the learner's replay_steps > 0",
            lambda: s if (s := stack.stats("learner")) and s.get("replay_steps", 0) > 0 else None,
            240,
        )
        grown = _wait(
            "the learner's replay to grow",
            lambda: (
                s
                if (s := stack.stats("learner")) and s["replay_steps"] > first["replay_steps"]
                else None
            ),
            120,
        )
        _log(f"replay grows: {first['replay_steps']:.0f} -> {grown['replay_steps']:.0f} steps")
        status = _wait(
            "the dashboard to answer 200",
            lambda: s if (s := stack.dashboard_status()) == 200 else None,
            120,
        )
        assert status == 200
        _log(f"phase 1 done at {time.monotonic() - t_start:.0f} s")

        # --- 2. kill one collector; scale to 4 ----------------------------------------------
        victims = stack.containers("collector")
        assert len(victims) == 3, victims
        victim = victims[0]
        victim_id = subprocess.run(
            ["docker", "inspect", "--format", "{{.Config.Hostname}}", victim],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        before = stack.collectors()
        subprocess.run(["docker", "kill", victim], check=True, capture_output=True)
        t_kill = time.monotonic()
        two = _wait(
            "GET /collectors to list 2 after SIGKILL of one",
            lambda: c if len(c := stack.collectors()) == 2 else None,
            90,
        )
        _log(
            f"collector {victim_id} killed; the API lists 2 after "
            f"{time.monotonic() - t_kill:.0f} s: {sorted(two)}"
        )
        assert victim_id not in two, f"the killed collector {victim_id} is still listed"

        def survivors_progressed() -> bool:
            now = stack.collectors()
            return len(now) == 2 and all(
                (now[c]["steps"] or 0) > (before[c]["steps"] or 0) for c in two
            )

        _wait("the two other collectors to keep stepping", survivors_progressed, 60)
        assert len(stack.collectors()) == 2, (
            "the killed collector came back by itself (a killed container stays down)"
        )

        out = stack.compose("up", "-d", "--no-build", "--no-recreate", "--scale", "collector=4")
        four = _wait(
            "4 live collectors after --scale collector=4",
            lambda: c if len(c := stack.collectors()) == 4 else None,
            240,
        )
        _log(f"scaled to 4: {sorted(four)}; phase 2 done at {time.monotonic() - t_start:.0f} s")
        assert set(two) <= set(four), f"scaling replaced running collectors:\n{out}"

        # --- 3. restart the learner: it resumes from the volume -----------------------------
        pre = _wait(
            "learner stats with a policy version",
            lambda: s if (s := stack.stats("learner")) and s.get("policy_version", 0) > 0 else None,
            180,
        )
        t_restart = time.time()
        stack.compose("restart", "learner")
        post = _wait(
            "stats from the restarted learner", lambda: stack.fresh_stats("learner", t_restart), 240
        )
        _log(
            f"learner restarted: policy_version {pre['policy_version']:.0f} -> "
            f"{post['policy_version']:.0f}, replay_steps {pre['replay_steps']:.0f} -> "
            f"{post['replay_steps']:.0f}, updates {pre.get('updates', 0):.0f} -> "
            f"{post.get('updates', 0):.0f}"
        )
        assert post["policy_version"] >= pre["policy_version"], (pre, post)
        assert post["replay_steps"] >= pre["replay_steps"], (pre, post)
        _log(f"phase 3 done at {time.monotonic() - t_start:.0f} s")

        # --- 4. down (volume kept) and up: repertoire and replay restored -------------------
        rep_pre = _wait(
            "repertoire stats with a non-empty archive",
            lambda: s if (s := stack.stats("repertoire")) and s.get("size", 0) > 0 else None,
            120,
        )
        learn_pre = stack.stats("learner")
        assert learn_pre is not None
        stack.compose("down", timeout=600)
        assert not stack.containers("learner"), "down left containers behind"
        t_up = time.time()
        stack.compose("up", "-d", "--no-build", "--scale", "collector=3")
        rep_post = _wait(
            "stats from the new repertoire", lambda: stack.fresh_stats("repertoire", t_up), 240
        )
        learn_post = _wait(
            "stats from the new learner", lambda: stack.fresh_stats("learner", t_up), 240
        )
        _log(
            f"down/up: repertoire size {rep_pre['size']:.0f} -> {rep_post['size']:.0f}, "
            f"replay_steps {learn_pre['replay_steps']:.0f} -> "
            f"{learn_post['replay_steps']:.0f}, policy_version "
            f"{learn_pre['policy_version']:.0f} -> {learn_post['policy_version']:.0f}"
        )
        assert rep_post["size"] >= rep_pre["size"] > 0, (rep_pre, rep_post)
        assert learn_post["replay_steps"] >= learn_pre["replay_steps"] > 0, (learn_pre, learn_post)
        assert learn_post["policy_version"] >= learn_pre["policy_version"], (learn_pre, learn_post)
        _wait(
            "3 live collectors after down/up",
            lambda: c if len(c := stack.collectors()) == 3 else None,
            240,
        )
        _log(f"phase 4 done at {time.monotonic() - t_start:.0f} s")
        ok = True
    finally:
        if not ok:
            dest = ROOT / "test-artifacts" / f"compose-{project}"
            try:
                stack.save_logs(dest)
                _log(f"container logs saved under {dest}")
            except Exception as e:  # the test's own failure matters more
                _log(f"could not save logs: {e}")
        stack.compose("down", "-v", "--remove-orphans", timeout=600, check=False)
        _log(f"stack removed; compose part took {time.monotonic() - t_start:.0f} s")
