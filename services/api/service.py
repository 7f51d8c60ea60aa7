"""HTTP API: a FastAPI app served by uvicorn, in its own process, fed from the bus.

Subscribes:  ursa/{run}/*/stats/** (Stats), ursa/{run}/repertoire/snapshot (RepertoireSnapshot;
             also queried at start and while none has arrived),
             ursa/{run}/evaluator/adapt_state/* (AdaptJob: adaptation jobs as they change)
Queries:     ursa/{run}/repertoire/sample (POST /skills/sample),
             ursa/{run}/evaluator/evaluate (POST /evaluate),
             ursa/{run}/evaluator/adapt/{eid} (POST /adapt),
             ursa/{run}/evaluator/adapt_job/* (GET /adapt/{id})
Liveliness:  watches ursa/{run}/alive/*/*; declares ursa/{run}/alive/api/main
Publishes:   ursa/{run}/api/stats (request counts)

Placement: a separate process rather than a thread of the repertoire or the dashboard, so that
HTTP traffic never slows the archive or the page, any of them can restart alone, and the API can
run on another machine like every other service. Its reads (skills, nearest, collectors,
stats) come from the latest snapshot and stats it keeps; sampling and evaluation are forwarded
to the service that owns them.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import uvicorn

from proto import ursa_pb2 as pb
from services.api.app import create_app
from services.api.bus import BusBackend
from services.api.state import ApiState
from services.common.bus import Presence, query_one, safe_handler, validate_with
from services.common.config import ServiceArgs, env_field, save_resolved
from services.common.live import LiveState
from services.common.runtime import ServiceRuntime
from ursa.adapt import adapt_dir
from ursa.bounds import declared
from ursa.envs import allowed_damages


@dataclass(frozen=True)
class ApiArgs(ServiceArgs):
    """HTTP API settings."""

    host: str = env_field("URSA_API_HOST", "127.0.0.1")
    """Address the HTTP server binds to (env URSA_API_HOST)."""
    port: int = env_field("URSA_API_PORT", "8000", int)
    """Port of the HTTP server (env URSA_API_PORT)."""
    max_eval_steps: int = 5000
    """Largest ``steps`` of ``POST /evaluate`` (422 above)."""
    max_sample: int = 4096
    """Largest ``n`` of ``POST /skills/sample`` (the repertoire's own limit)."""
    eval_timeout_s: float = 30.0
    """Fixed part of the time an evaluation may take before the API answers 503."""
    eval_timeout_per_step_s: float = 0.05
    """Per-step part of that time."""
    max_adapt_budget: int = 200
    """Largest trial budget of ``POST /adapt`` (the evaluator's own limit)."""
    max_adapt_skills: int = 5000
    """Largest map of ``POST /adapt`` (the evaluator's own limit)."""
    adapt_timeout_s: float = 10.0
    """How long ``/adapt`` waits for an evaluator (it answers between two rollouts)."""


def _joints(env: str) -> int:
    """Joints an adaptation job may freeze on ``env``."""
    if env == "a1":
        from ursa.envs.a1 import JOINT_NAMES

        return len(JOINT_NAMES)
    return 0


class ApiService:
    """The API process: bus session + live state + uvicorn."""

    def __init__(self, args: ApiArgs) -> None:
        self.args = args
        validate_with(args.core)  # every message decoded is checked against the run's bounds
        self.rt = ServiceRuntime("api", "main", args.bus, args.run)
        self.log = self.rt.log
        save_resolved(args, args.run, "api")
        t = self.rt.topics
        self.presence = Presence(self.rt.session, t.alive())
        self.live = LiveState(args.run.run_id, alive=self.presence.alive)
        drops = self.rt.drops
        self.subs = [
            self.rt.session.declare_subscriber(
                t.all_stats, safe_handler(pb.Stats, self.live.on_stats, drops, args.run.run_id)
            ),
            self.rt.session.declare_subscriber(
                t.snapshot,
                safe_handler(pb.RepertoireSnapshot, self.live.on_snapshot, drops, args.run.run_id),
            ),
        ]
        backend = BusBackend(self.rt, args.bus.router)
        self.state = ApiState(
            live=self.live,
            backend=backend,
            env=args.core.env,
            skill_dim=args.core.skill_dim,
            skill_box=declared(args.core).samples,
            max_eval_steps=args.max_eval_steps,
            max_sample=args.max_sample,
            eval_timeout_s=args.eval_timeout_s,
            eval_timeout_per_step_s=args.eval_timeout_per_step_s,
            damages=allowed_damages(args.core.env),
            adapt_backend=backend,
            joints=_joints(args.core.env),
            jobs_dir=adapt_dir(args.run.dir) / "jobs",
            max_adapt_budget=args.max_adapt_budget,
            max_adapt_skills=args.max_adapt_skills,
            adapt_timeout_s=args.adapt_timeout_s,
        )
        self.subs.append(
            self.rt.session.declare_subscriber(
                t.adapt_state("*"),
                safe_handler(
                    pb.AdaptJob, lambda m, _k: self.state.on_adapt_state(m), drops, args.run.run_id
                ),
            )
        )
        self.app = create_app(self.state)
        self.server = uvicorn.Server(
            uvicorn.Config(
                self.app, host=args.host, port=args.port, log_level="warning", access_log=False
            )
        )
        self._bg = threading.Thread(target=self._background, daemon=True, name="api-bus")

    def _query_snapshot(self) -> None:
        msg = query_one(
            self.rt.session, self.rt.topics.snapshot, pb.RepertoireSnapshot, timeout_s=1.0
        )
        if msg is not None:
            try:
                self.live.on_snapshot(msg)
            except Exception as e:
                self.rt.drops.add("malformed")
                self.log.warning("bad snapshot reply: %s", e)

    def _background(self) -> None:
        """Snapshot queries until one arrives, ready line, stats once a second."""
        announced = False
        last_query = 0.0
        while not self.rt.stop.is_set():
            now = time.monotonic()
            if self.live.latest_snapshot() is None and now - last_query > 3.0:
                self._query_snapshot()
                last_query = now
            if not announced and self.server.started:
                print(
                    f"API READY http://{self.args.host}:{self.args.port} (docs: /docs)", flush=True
                )
                announced = True
            snap = self.live.latest_snapshot()
            self.rt.publish_stats(
                {
                    **{k: float(v) for k, v in self.state.counters().items()},
                    "snapshot_version": snap.version if snap is not None else -1,
                    "evaluating": float(self.state.eval_lock.locked()),
                }
            )
            self.rt.stop.wait(1.0)

    def run(self) -> None:
        """Serve until SIGINT/SIGTERM (uvicorn installs the handlers)."""
        self._bg.start()
        try:
            self.server.run()
        finally:
            self.rt.stop.set()

    def close(self) -> None:
        self.rt.stop.set()
        if self._bg.is_alive():
            self._bg.join(timeout=2.0)
        self.presence.undeclare()
        for s in self.subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self.rt.close()
