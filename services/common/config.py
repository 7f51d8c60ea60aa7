"""Configs shared by every service: where the bus is and which run directory to use."""

from __future__ import annotations

import hashlib
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ursa.plain import to_plain


@dataclass(frozen=True)
class BusConfig:
    """How a process reaches the Zenoh bus."""

    router: str = os.environ.get("URSA_ROUTER", "tcp/127.0.0.1:7447")
    """Endpoint of the router every process connects to as a client (env URSA_ROUTER)."""
    listen: str = os.environ.get("URSA_ROUTER_LISTEN", "tcp/127.0.0.1:7447")
    """Endpoint the router listens on (router only; env URSA_ROUTER_LISTEN)."""
    connect_timeout_s: float = 30.0
    """How long a client retries connecting to the router at start-up before giving up."""


@dataclass(frozen=True)
class RunConfig:
    """Which run this process belongs to and where its files live."""

    run_id: str = os.environ.get("URSA_RUN_ID", "default")
    """Run identifier: a key chunk of every topic and the run directory's name (env URSA_RUN_ID)."""
    root: Path = Path(os.environ.get("URSA_RUNS_DIR", "runs"))
    """Directory holding run directories (env URSA_RUNS_DIR)."""

    @property
    def dir(self) -> Path:
        """The run directory ``<root>/<run_id>``."""
        return self.root / self.run_id


def config_hash(obj: Any) -> str:
    """Short stable hash of a config tree."""
    blob = json.dumps(to_plain(obj), sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def save_resolved(cfg: Any, run: RunConfig, name: str) -> Path:
    """Write the resolved config of a service to ``<run dir>/config/<name>.yaml``."""
    path = run.dir / "config" / f"{name}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".yaml.tmp")
    tmp.write_text(yaml.safe_dump({"argv": sys.argv[1:], "config": to_plain(cfg)}, sort_keys=False))
    os.replace(tmp, path)
    return path
