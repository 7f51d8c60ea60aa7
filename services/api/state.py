"""What the HTTP routes read and call: the live view of the run and a backend for queries.

The routes never touch zenoh: :class:`ApiState` holds a ``LiveState`` (fed by bus callbacks in the
service, or directly by tests) and a :class:`Backend` that forwards sample and evaluate requests
(``services.api.bus.BusBackend`` over Zenoh queries; a fake in tests).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from proto import ursa_pb2 as pb
from services.common.live import LiveState
from ursa.bounds import Box

MAX_JOBS = 256
"""Job states the API keeps from the bus (the run directory keeps them all)."""


class AdaptBackend(Protocol):
    """Adaptation jobs the API forwards to the evaluators."""

    def adapt(self, req: pb.AdaptRequest, evaluator: str, timeout_s: float) -> pb.AdaptJob | None:
        """Evaluator ``evaluator``'s reply to a job request, or None if it did not answer."""
        ...

    def adapt_job(self, job_id: str, timeout_s: float) -> pb.AdaptJob | None:
        """The state of a job from the evaluator holding it, or None if none answered."""
        ...

    def header(self) -> pb.Header:
        """A header for outgoing requests."""
        ...


class Backend(Protocol):
    """Requests the API forwards to other services."""

    def sample(self, n: int, seed: int | None, timeout_s: float) -> pb.SkillReply | None:
        """The repertoire's reply to a ``SkillRequest``, or None if nobody answered."""
        ...

    def evaluate(self, req: pb.EvaluateRequest, timeout_s: float) -> pb.EvaluateReply | None:
        """The evaluator's reply, or None if nobody answered in time."""
        ...

    def bus_status(self) -> dict[str, Any]:
        """``{"connected": bool, "router": str, ...}``: whether the router is reachable."""
        ...

    def header(self) -> pb.Header:
        """A header for outgoing requests."""
        ...


@dataclass
class ApiState:
    """Everything the app needs; build it with a ``LiveState`` and (optionally) a backend."""

    live: LiveState
    backend: Backend | None = None
    env: str = "point"
    """Environment of the run (which damages exist)."""
    skill_dim: int | None = None
    """Skill dimension from the config: the length of every skill the OpenAPI schema states and
    the API accepts (None: unknown, checked against the latest snapshot instead)."""
    skill_box: Box | None = None
    """Box of the skills an evaluation may ask for (``ursa.bounds.declared(cfg).samples``, which
    the evaluator enforces); stated per coordinate in the schema. None: any finite value."""
    max_eval_steps: int = 5000
    """Largest ``steps`` of ``POST /evaluate``."""
    max_sample: int = 4096
    """Largest ``n`` of ``POST /skills/sample``."""
    sample_timeout_s: float = 2.0
    eval_timeout_s: float = 30.0
    """Fixed part of an evaluation's timeout."""
    eval_timeout_per_step_s: float = 0.05
    """Per-step part of an evaluation's timeout (the A1 runs far faster than 20 steps/s)."""
    eval_wait_s: float = 120.0
    """How long a request waits for the evaluation before it (they run one at a time)."""
    damages: tuple[str, ...] = ("", "none")
    adapt_backend: AdaptBackend | None = None
    """Forwards adaptation jobs (None: ``POST /adapt`` answers 503)."""
    joints: int = 0
    """Joints a job may freeze (A1: 12, ``ursa.envs.a1.JOINT_NAMES``; other envs: none)."""
    jobs_dir: Path | None = None
    """``<run>/eval/adapt/jobs``: where evaluators persist jobs (read when none answers)."""
    max_adapt_budget: int = 200
    max_adapt_skills: int = 5000
    adapt_timeout_s: float = 10.0
    """How long a job request or state query waits for the evaluator (it answers between two
    rollouts)."""
    adapt_jobs: dict[str, pb.AdaptJob] = field(default_factory=dict)
    """Latest state of each job published on the bus (newest ``MAX_JOBS``)."""
    started: float = field(default_factory=time.time)
    eval_lock: threading.Lock = field(default_factory=threading.Lock)
    requests: dict[str, int] = field(default_factory=dict)
    _count_lock: threading.Lock = field(default_factory=threading.Lock)

    def count(self, status: int) -> None:
        key = f"http_{status // 100}xx"
        with self._count_lock:
            self.requests[key] = self.requests.get(key, 0) + 1
            self.requests["http_total"] = self.requests.get("http_total", 0) + 1

    def on_adapt_state(self, msg: pb.AdaptJob) -> None:
        """Keep a job's newest published state."""
        with self._count_lock:
            cur = self.adapt_jobs.get(msg.job_id)
            if cur is None or msg.updated >= cur.updated:
                self.adapt_jobs.pop(msg.job_id, None)
                self.adapt_jobs[msg.job_id] = msg
            while len(self.adapt_jobs) > MAX_JOBS:
                self.adapt_jobs.pop(next(iter(self.adapt_jobs)))

    def cached_job(self, job_id: str) -> pb.AdaptJob | None:
        with self._count_lock:
            return self.adapt_jobs.get(job_id)

    def counters(self) -> dict[str, int]:
        with self._count_lock:
            return dict(self.requests)
