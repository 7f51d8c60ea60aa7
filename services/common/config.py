"""Configs shared by every service: where the bus is and which run directory to use."""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml

from ursa.config import Config
from ursa.plain import to_plain
from ursa.rundir import RunDir, atomic_write

T = TypeVar("T")


def env_field(var: str, default: str, cast: Callable[[str], T] = str) -> T:  # type: ignore[assignment]
    """A dataclass field whose default is the environment variable ``var`` (else ``default``),
    read when the config is made (not when its module is imported), through ``cast``."""
    return field(default_factory=lambda: cast(os.environ.get(var, default)))


def _wandb_mode() -> Literal["off", "offline", "online"]:
    mode = os.environ.get("URSA_WANDB", "off")
    return mode if mode in ("offline", "online") else "off"  # type: ignore[return-value]


@dataclass(frozen=True)
class BusConfig:
    """How a process reaches the Zenoh bus."""

    router: str = env_field("URSA_ROUTER", "tcp/127.0.0.1:7447")
    """Endpoint of the router every process connects to as a client (env URSA_ROUTER)."""
    listen: str = env_field("URSA_ROUTER_LISTEN", "tcp/127.0.0.1:7447")
    """Endpoint the router listens on (router only; env URSA_ROUTER_LISTEN)."""
    connect_timeout_s: float = 30.0
    """How long a client retries connecting to the router at start-up before giving up."""
    auth: str = env_field("URSA_BUS_AUTH", "auto")
    """Router authentication and access control: ``on``, ``off`` or ``auto`` (on when an
    endpoint is not loopback or the run's secrets exist; env URSA_BUS_AUTH). See
    services/common/secrets.py."""
    secrets: str = env_field("URSA_SECRETS_DIR", "")
    """Directory of the run's secrets (bus key, credentials); empty: ``<run dir>/secrets``
    (env URSA_SECRETS_DIR)."""
    key_file: str = env_field("URSA_BUS_KEY_FILE", "")
    """Run key (hex) of the bus frames' MACs; empty: ``bus.key`` of the secrets directory when
    it exists, else checksums only (env URSA_BUS_KEY_FILE)."""
    credentials: str = env_field("URSA_BUS_CREDENTIALS", "")
    """File holding this client's ``user:password``; empty: ``<secrets>/<service>.cred``
    (env URSA_BUS_CREDENTIALS)."""


@dataclass(frozen=True)
class RunConfig:
    """Which run this process belongs to and where its files live."""

    run_id: str = env_field("URSA_RUN_ID", "default")
    """Run identifier: a key chunk of every topic and the run directory's name (env URSA_RUN_ID)."""
    root: Path = env_field("URSA_RUNS_DIR", "runs", Path)
    """Directory holding run directories (env URSA_RUNS_DIR)."""
    metrics_every_s: float = env_field("URSA_METRICS_EVERY_S", "5", float)
    """Stats are written to the run's metrics (JSONL, TensorBoard, W&B) at most this often
    (env URSA_METRICS_EVERY_S)."""
    wandb: Literal["off", "offline", "online"] = field(default_factory=_wandb_mode)
    """Also log stats to Weights & Biases: offline (files under <run>/wandb, ``wandb sync``
    uploads them) or online; needs the wandb extra (env URSA_WANDB)."""

    @property
    def dir(self) -> Path:
        """The run directory ``<root>/<run_id>``."""
        return self.root / self.run_id


@dataclass(frozen=True)
class ServiceArgs:
    """What every service's args begin with."""

    core: Config = field(default_factory=Config)
    """The algorithm's config: ``--preset``, ``--env`` and ``--feature`` pick its defaults,
    and any of its fields can be set by a flag (``--core.learner.batch-size 8``)."""
    bus: BusConfig = field(default_factory=BusConfig)
    """How this process reaches the bus."""
    run: RunConfig = field(default_factory=RunConfig)
    """The run this process belongs to."""


def config_hash(obj: Any) -> str:
    """Short stable hash of a config tree."""
    blob = json.dumps(to_plain(obj), sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def save_resolved(cfg: Any, run: RunConfig, name: str) -> Path:
    """Write the resolved config of a service to ``<run dir>/config/<name>.yaml``."""
    doc = {"argv": sys.argv[1:], "config": to_plain(cfg)}
    return atomic_write(RunDir(run.dir).config_file(name), yaml.safe_dump(doc, sort_keys=False))
