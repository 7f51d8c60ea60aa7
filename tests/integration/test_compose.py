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
``test-artifacts/compose-<project>/`` (the start-up, removal and image build are
``tests/integration/compose.py``'s, shared with ``test_compose_faults.py``). Skips only where no
Docker engine answers (fails where one does but Compose is missing).
Env: URSA_BASE_IMAGE (default ursa-base:bookworm, built here), URSA_TEST_IMAGE (ursa:test),
URSA_TEST_COLLECTOR_ARGS (default ``--realtime-factor 25``: collectors throttled to 25x real time).
"""

from __future__ import annotations

import subprocess
import time

import pytest

from tests.integration.compose import (
    compose_stack,
    log,
    wait,
)

pytestmark = [pytest.mark.slow, pytest.mark.docker]


@pytest.mark.timeout(3600)
def test_compose_stack_scales_and_survives_faults(image: str) -> None:
    with compose_stack(
        image,
        project_prefix="ursatest",
        run_id="compose-test",
        # Unthrottled point-mass collectors outrun the repertoire and starve a small machine
        # (9 containers on 2 cores); 25x real time still fills the replay by hundreds of steps/s.
        realtime_factor=25,
    ) as stack:
        t_start = time.monotonic()
        # --- 1. up with 3 collectors --------------------------------------------------------
        log(
            f"project {stack.project}: up --scale collector=3 "
            f"(API :{stack.env['URSA_API_PORT']}, dashboard :{stack.env['URSA_DASHBOARD_PORT']})"
        )
        stack.compose("up", "-d", "--no-build", "--scale", "collector=3")
        wait("the API to answer /health", lambda: stack.get("/health"), 240)
        three = wait(
            "3 live collectors in GET /collectors",
            lambda: c if len(c := stack.collectors()) == 3 else None,
            240,
        )
        log(f"3 collectors alive: {sorted(three)}")
        first = wait(
            "the learner's replay_steps > 0",
            lambda: s if (s := stack.stats("learner")) and s.get("replay_steps", 0) > 0 else None,
            240,
        )
        grown = wait(
            "the learner's replay to grow",
            lambda: (
                s
                if (s := stack.stats("learner")) and s["replay_steps"] > first["replay_steps"]
                else None
            ),
            120,
        )
        log(f"replay grows: {first['replay_steps']:.0f} -> {grown['replay_steps']:.0f} steps")
        status = wait(
            "the dashboard to answer 200",
            lambda: s if (s := stack.dashboard_status()) == 200 else None,
            120,
        )
        assert status == 200
        log(f"phase 1 done at {time.monotonic() - t_start:.0f} s")

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
        two = wait(
            "GET /collectors to list 2 after SIGKILL of one",
            lambda: c if len(c := stack.collectors()) == 2 else None,
            90,
        )
        log(
            f"collector {victim_id} killed; the API lists 2 after "
            f"{time.monotonic() - t_kill:.0f} s: {sorted(two)}"
        )
        assert victim_id not in two, f"the killed collector {victim_id} is still listed"

        def survivors_progressed() -> bool:
            now = stack.collectors()
            return len(now) == 2 and all(
                (now[c]["steps"] or 0) > (before[c]["steps"] or 0) for c in two
            )

        wait("the two other collectors to keep stepping", survivors_progressed, 60)
        assert len(stack.collectors()) == 2, (
            "the killed collector came back by itself (a killed container stays down)"
        )

        out = stack.compose("up", "-d", "--no-build", "--no-recreate", "--scale", "collector=4")
        four = wait(
            "4 live collectors after --scale collector=4",
            lambda: c if len(c := stack.collectors()) == 4 else None,
            240,
        )
        log(f"scaled to 4: {sorted(four)}; phase 2 done at {time.monotonic() - t_start:.0f} s")
        assert set(two) <= set(four), f"scaling replaced running collectors:\n{out}"

        # --- 3. restart the learner: it resumes from the volume -----------------------------
        pre = wait(
            "learner stats with a policy version",
            lambda: s if (s := stack.stats("learner")) and s.get("policy_version", 0) > 0 else None,
            180,
        )
        t_restart = time.time()
        stack.compose("restart", "learner")
        post = wait(
            "stats from the restarted learner", lambda: stack.fresh_stats("learner", t_restart), 240
        )
        log(
            f"learner restarted: policy_version {pre['policy_version']:.0f} -> "
            f"{post['policy_version']:.0f}, replay_steps {pre['replay_steps']:.0f} -> "
            f"{post['replay_steps']:.0f}, updates {pre.get('updates', 0):.0f} -> "
            f"{post.get('updates', 0):.0f}"
        )
        assert post["policy_version"] >= pre["policy_version"], (pre, post)
        assert post["replay_steps"] >= pre["replay_steps"], (pre, post)
        log(f"phase 3 done at {time.monotonic() - t_start:.0f} s")

        # --- 4. down (volume kept) and up: repertoire and replay restored -------------------
        rep_pre = wait(
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
        rep_post = wait(
            "stats from the new repertoire", lambda: stack.fresh_stats("repertoire", t_up), 240
        )
        learn_post = wait(
            "stats from the new learner", lambda: stack.fresh_stats("learner", t_up), 240
        )
        log(
            f"down/up: repertoire size {rep_pre['size']:.0f} -> {rep_post['size']:.0f}, "
            f"replay_steps {learn_pre['replay_steps']:.0f} -> "
            f"{learn_post['replay_steps']:.0f}, policy_version "
            f"{learn_pre['policy_version']:.0f} -> {learn_post['policy_version']:.0f}"
        )
        assert rep_post["size"] >= rep_pre["size"] > 0, (rep_pre, rep_post)
        assert learn_post["replay_steps"] >= learn_pre["replay_steps"] > 0, (learn_pre, learn_post)
        assert learn_post["policy_version"] >= learn_pre["policy_version"], (learn_pre, learn_post)
        wait(
            "3 live collectors after down/up",
            lambda: c if len(c := stack.collectors()) == 3 else None,
            240,
        )
        log(f"phase 4 done at {time.monotonic() - t_start:.0f} s")
