"""The run directory: its layout, the one durable atomic write and the metrics row.

Every file of a run (``<runs>/<run_id>/``, written by the services or by
:func:`ursa.eval.loading.save_serial_run`) is named here, and only here::

    config/<service>.yaml            resolved config: {"argv": [...], "config": {...}}
    checkpoints/learner.pt           Learner.save_checkpoint
    checkpoints/learner_state.json   {"samples", "weights_version", "updates", "stamp"}
    repertoire/archive.npz           Repertoire.save
    replay/segment-<n>.mcap          the learner's replay (services.learner.replay_store)
    metrics/<service>-<id>.jsonl     one stats row per line
    collectors/<id>.json             {"incarnation", "started"} of each collector id
    tensorboard/<service>-<id>…/     TensorBoard event files
    wandb/                           offline W&B runs (written by wandb itself)
    secrets/                         router credentials (``ursa secrets``)
    eval/                            default output of ``ursa eval``

Every file that is replaced whole goes through :func:`atomic_write`: readers (a restarting
service, ``ursa eval`` on a live run) see the old content or the new one, never a torn file, and
the new one survives a power cut once the call returns.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

CONFIG = Path("config")
CHECKPOINTS = Path("checkpoints")
CHECKPOINT = CHECKPOINTS / "learner.pt"
LEARNER_STATE = CHECKPOINTS / "learner_state.json"
ARCHIVE = Path("repertoire") / "archive.npz"
REPLAY = Path("replay")
METRICS = Path("metrics")
COLLECTORS = Path("collectors")
TENSORBOARD = Path("tensorboard")
WANDB = Path("wandb")
SECRETS = Path("secrets")
EVAL = Path("eval")

LAYOUT = (
    CONFIG,
    CHECKPOINTS,
    ARCHIVE.parent,
    REPLAY,
    METRICS,
    COLLECTORS,
    TENSORBOARD,
    WANDB,
    SECRETS,
    EVAL,
)
"""The top-level entries a run directory may hold."""


class RunDir:
    """The paths of one run directory (nothing is created until something is written)."""

    __slots__ = ("root",)

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)
        """The run directory itself, ``<runs>/<run_id>``."""

    def __repr__(self) -> str:
        return f"RunDir({str(self.root)!r})"

    @property
    def config(self) -> Path:
        return self.root / CONFIG

    def config_file(self, service: str) -> Path:
        """The resolved config of one service (``serial`` for a single-process run)."""
        return self.config / f"{service}.yaml"

    @property
    def checkpoints(self) -> Path:
        return self.root / CHECKPOINTS

    @property
    def checkpoint(self) -> Path:
        return self.root / CHECKPOINT

    @property
    def learner_state(self) -> Path:
        return self.root / LEARNER_STATE

    @property
    def archive(self) -> Path:
        return self.root / ARCHIVE

    @property
    def replay(self) -> Path:
        return self.root / REPLAY

    @property
    def metrics(self) -> Path:
        return self.root / METRICS

    def metrics_file(self, service: str, sid: str) -> Path:
        return self.metrics / f"{service}-{sid}.jsonl"

    @property
    def collectors(self) -> Path:
        return self.root / COLLECTORS

    def collector_file(self, cid: str) -> Path:
        return self.collectors / f"{cid}.json"

    @property
    def tensorboard(self) -> Path:
        """The directory to point ``tensorboard --logdir`` at."""
        return self.root / TENSORBOARD

    @property
    def wandb(self) -> Path:
        return self.root / WANDB

    @property
    def secrets(self) -> Path:
        return self.root / SECRETS

    @property
    def eval(self) -> Path:
        return self.root / EVAL


TEMP_SUFFIX = ".tmp"
"""Suffix of atomic_write's temporary files (``<name>.<random>.tmp`` beside the target)."""


def metrics_row(
    t: float,
    service: str,
    sid: str,
    scalars: dict[str, float],
    labels: dict[str, str] | None = None,
) -> dict[str, Any]:
    """One line of ``metrics/<service>-<id>.jsonl`` (a service's stats row, or a serial run's):
    ``{"t", "service", "id", "scalars", "labels"}``, ``t`` in seconds since the epoch."""
    return {
        "t": t,
        "service": service,
        "id": sid,
        "scalars": {k: float(v) for k, v in scalars.items()},
        "labels": dict(labels or {}),
    }


def atomic_write(
    path: str | os.PathLike[str], data: str | bytes | Callable[[BinaryIO], object]
) -> Path:
    """Replace ``path`` with ``data`` (text as UTF-8, bytes, or a function writing to a binary
    file) atomically and durably; returns the path.

    The data goes to a temporary file of a unique name in the same directory, which is flushed
    and fsynced, renamed over ``path`` (os.replace), and the directory fsynced so that the
    rename itself is on disk. If anything raises (a serializer midway, a full disk), ``path``
    keeps its old content and the temporary file is removed. Concurrent writers each use their
    own temporary file: the last rename wins, whole. Created files get the mode ``open()``
    would give them (0o666 less the umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=TEMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())
            if callable(data):
                data(f)
            else:
                f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)
    return path


def _fsync_dir(directory: Path) -> None:
    # The new content is in place once os.replace returned; a filesystem that cannot fsync a
    # directory (some network and FUSE mounts) costs only the rename's durability, not the write.
    with contextlib.suppress(OSError):
        dfd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def _umask() -> int:
    # /proc gives the umask without changing it (os.umask would, for every thread, briefly).
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


__all__ = [
    "ARCHIVE",
    "CHECKPOINT",
    "LAYOUT",
    "LEARNER_STATE",
    "RunDir",
    "atomic_write",
]
