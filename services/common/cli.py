"""Command-line helpers shared by services: presets, logging, signals."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any, TypeVar

import tyro

from ursa.config import PresetName, preset

T = TypeVar("T")
PRESETS: tuple[PresetName, ...] = ("tiny", "small", "paper")


def split_preset(argv: Sequence[str]) -> tuple[PresetName, str | None, list[str]]:
    """Take ``--preset NAME`` and ``--env NAME`` out of argv (they pick the defaults)."""
    name: str = os.environ.get("URSA_PRESET", "small")
    env: str | None = os.environ.get("URSA_ENV") or None
    rest: list[str] = []
    it = iter(argv)
    for a in it:
        if a in ("--preset", "--env"):
            val = next(it, None)
            if val is None:
                raise SystemExit(f"{a} needs a value")
            if a == "--preset":
                name = val
            else:
                env = val
        elif a.startswith("--preset="):
            name = a.split("=", 1)[1]
        elif a.startswith("--env="):
            env = a.split("=", 1)[1]
        else:
            rest.append(a)
    if name not in PRESETS:
        raise SystemExit(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    if env is not None and env not in ("a1", "point"):
        raise SystemExit(f"unknown env {env!r}; choose a1 or point")
    return name, env, rest  # type: ignore[return-value]


def parse(cls: type[T], argv: Sequence[str] | None = None, description: str | None = None) -> T:
    """Parse a service config whose ``core`` field defaults to the chosen preset."""
    args = list(sys.argv[1:] if argv is None else argv)
    name, env, rest = split_preset(args)
    default: Any = cls(core=preset(name, env))  # type: ignore[call-arg]
    return tyro.cli(cls, default=default, args=rest, description=description)


def setup_logging(name: str) -> logging.Logger:
    level = os.environ.get("URSA_LOG_LEVEL", "INFO").upper()
    logging.basicConfig(
        level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stdout
    )
    return logging.getLogger(name)


def stop_event() -> threading.Event:
    """An event set by SIGTERM or SIGINT."""
    ev = threading.Event()

    def _set(*_: Any) -> None:
        ev.set()

    signal.signal(signal.SIGTERM, _set)
    signal.signal(signal.SIGINT, _set)
    return ev
