"""Where a service's stats land on disk: JSONL, TensorBoard event files and, optionally, W&B.

Every row of scalars a service publishes (at most every ``RunConfig.metrics_every_s``) goes to

- ``<run>/metrics/<service>-<id>.jsonl``: one JSON object per line, the project's own format
  (``ursa eval curves`` reads it);
- ``<run>/tensorboard/<service>-<id>[.<axis>]/events.out.tfevents.*``: the same scalars through
  torch's ``SummaryWriter``, one TensorBoard run per (service, id, step axis). The step of each
  row is one of its own scalars, chosen per service by :data:`STEP_AXES`: the learner's
  ``updates`` (and again at its ``ingested_steps``, the env steps it trained on, in the
  ``learner-<id>.env_steps`` run), a collector's env ``steps``, the repertoire's ``commits``; any
  other service counts its rows. Open them with ``tensorboard --logdir <run>/tensorboard``;
- Weights & Biases when ``RunConfig.wandb`` is ``offline`` (the default of ``ursa up --wandb``:
  files under ``<run>/wandb/``, uploaded later with ``wandb sync``) or ``online``: one W&B run per
  process, grouped by run id, with the step axes declared as its step metrics.

A sink that fails (a full disk, W&B missing) is logged once and dropped; stats never stop a
service.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path
from typing import IO, Any, Literal, Protocol

from ursa.rundir import RunDir, metrics_row

log = logging.getLogger(__name__)

STEP_AXES: dict[str, tuple[tuple[str, str], ...]] = {
    "learner": (("updates", ""), ("ingested_steps", ".env_steps")),
    "collector": (("steps", ""),),
    "evaluator": (("evaluations", ""),),
    "repertoire": (("commits", ""),),
}
"""Per service: (scalar used as the TensorBoard step, suffix of the TensorBoard run's name).
Services not listed step by their row count."""

ROW_AXIS = "rows"
"""The step of services without a step scalar: rows written by this process."""


def tensorboard_dir(run_dir: Path) -> Path:
    """The directory to point ``tensorboard --logdir`` at."""
    return RunDir(run_dir).tensorboard


def tensorboard_command(run_dir: Path) -> str:
    """The shell command that opens TensorBoard on a run (the ``tensorboard`` installed beside
    this Python when there is one)."""
    exe = Path(sys.executable).parent / "tensorboard"
    return f"{exe if exe.exists() else 'tensorboard'} --logdir {tensorboard_dir(run_dir)}"


class Sink(Protocol):
    def write(self, t: float, scalars: dict[str, float], labels: dict[str, str]) -> None: ...

    def close(self) -> None: ...


class JsonlSink:
    """``<run>/metrics/<service>-<id>.jsonl``, appended and flushed per row."""

    def __init__(self, run_dir: Path, service: str, sid: str) -> None:
        self.path = RunDir(run_dir).metrics_file(service, sid)
        self.service, self.sid = service, sid
        self._file: IO[str] | None = None

    def write(self, t: float, scalars: dict[str, float], labels: dict[str, str]) -> None:
        if self._file is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "a")  # noqa: SIM115 - open for the service's life
        row = metrics_row(t, self.service, self.sid, scalars, labels)
        self._file.write(json.dumps(row) + "\n")
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def step_axes(service: str) -> tuple[tuple[str, str], ...]:
    """The (step scalar, run-name suffix) pairs of a service's TensorBoard runs."""
    return STEP_AXES.get(service, ((ROW_AXIS, ""),))


class TensorBoardSink:
    """One ``SummaryWriter`` per step axis of the service, flushed after every row (a service
    killed with SIGKILL keeps what it wrote)."""

    def __init__(self, run_dir: Path, service: str, sid: str) -> None:
        self.root = tensorboard_dir(run_dir)
        self.name = f"{service}-{sid}"
        self.axes = step_axes(service)
        self._writers: dict[str, Any] = {}
        self._rows = 0

    def _writer(self, suffix: str) -> Any:
        w = self._writers.get(suffix)
        if w is None:
            # torch's writer (tensorboard's own event format, no TensorFlow); imported here so
            # that a service pays for it only once it logs
            from torch.utils.tensorboard import SummaryWriter

            w = SummaryWriter(log_dir=str(self.root / f"{self.name}{suffix}"))
            self._writers[suffix] = w
        return w

    def write(self, t: float, scalars: dict[str, float], labels: dict[str, str]) -> None:
        self._rows += 1
        for key, suffix in self.axes:
            step = self._rows if key == ROW_AXIS else scalars.get(key)
            if step is None:
                continue
            w = self._writer(suffix)
            for tag, v in scalars.items():
                w.add_scalar(tag, float(v), global_step=int(step), walltime=t)
            w.flush()

    def close(self) -> None:
        for w in self._writers.values():
            w.close()
        self._writers.clear()


class WandbSink:
    """One W&B run of this process (``mode`` offline or online), grouped by the run id."""

    def __init__(
        self, run_dir: Path, run_id: str, service: str, sid: str, mode: Literal["offline", "online"]
    ) -> None:
        try:
            import wandb
        except ImportError as e:
            raise RuntimeError(
                "W&B logging needs the wandb extra (pip install -e '.[wandb]')"
            ) from e
        d = Path(run_dir)
        d.mkdir(parents=True, exist_ok=True)
        self._run = wandb.init(
            project=os.environ.get("WANDB_PROJECT", "ursa"),
            group=run_id,
            name=f"{service}-{sid}",
            job_type=service,
            dir=str(d),
            mode=mode,
            config={"run_id": run_id, "service": service, "id": sid},
            settings=wandb.Settings(
                silent=True, console="off", disable_git=True, x_disable_stats=True
            ),
        )
        axes = [k for k, _ in step_axes(service)]
        for k in axes:
            self._run.define_metric(k)
        self._run.define_metric("*", step_metric=axes[0])
        self._rows = 0

    def write(self, t: float, scalars: dict[str, float], labels: dict[str, str]) -> None:
        self._rows += 1
        self._run.log({**scalars, ROW_AXIS: self._rows})

    def close(self) -> None:
        self._run.finish()


class MetricsLog:
    """All sinks of one service process; see the module docstring."""

    def __init__(
        self,
        run_dir: Path,
        run_id: str,
        service: str,
        sid: str,
        wandb_mode: Literal["off", "offline", "online"] = "off",
    ) -> None:
        self.sinks: list[Sink] = [
            JsonlSink(run_dir, service, sid),
            TensorBoardSink(run_dir, service, sid),
        ]
        if wandb_mode != "off":
            try:  # a W&B that cannot start costs its sink, not the service
                self.sinks.append(WandbSink(run_dir, run_id, service, sid, wandb_mode))
            except Exception as e:
                log.error("W&B logging off: %s", e)

    def write(self, t: float, scalars: dict[str, float], labels: dict[str, str]) -> None:
        for s in list(self.sinks):
            try:
                s.write(t, scalars, labels)
            except Exception as e:
                log.error("metrics sink %s dropped: %s", type(s).__name__, e)
                self.sinks.remove(s)

    def close(self) -> None:
        for s in self.sinks:
            try:
                s.close()
            except Exception as e:
                log.warning("closing metrics sink %s: %s", type(s).__name__, e)
        self.sinks.clear()
