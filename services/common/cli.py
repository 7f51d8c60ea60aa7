"""Command-line helpers shared by services: presets, logging, signals."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import typing
from collections.abc import Sequence
from typing import Any, TypeVar

import tyro

from ursa.config import PresetName, preset

T = TypeVar("T")
PRESETS: tuple[PresetName, ...] = typing.get_args(PresetName)


_PICKERS = ("--preset", "--env", "--feature")


def split_preset(argv: Sequence[str]) -> tuple[dict[str, str | None], list[str]]:
    """Take ``--preset``, ``--env`` and ``--feature`` out of argv: they pick the defaults of
    every other field (env vars URSA_PRESET, URSA_ENV, URSA_FEATURE)."""
    picked: dict[str, str | None] = {
        "preset": os.environ.get("URSA_PRESET", "small"),
        "env": os.environ.get("URSA_ENV") or None,
        "feature": os.environ.get("URSA_FEATURE") or None,
    }
    rest: list[str] = []
    it = iter(argv)
    for a in it:
        flag, _, val = a.partition("=")
        if flag in _PICKERS:
            if not val:
                val = next(it, "")
                if not val:
                    raise SystemExit(f"{flag} needs a value")
            picked[flag[2:]] = val
        else:
            rest.append(a)
    if picked["preset"] not in PRESETS:
        raise SystemExit(f"unknown preset {picked['preset']!r}; choose one of {', '.join(PRESETS)}")
    if picked["env"] not in (None, "a1", "point"):
        raise SystemExit(f"unknown env {picked['env']!r}; choose a1 or point")
    return picked, rest


def parse(cls: type[T], argv: Sequence[str] | None = None, description: str | None = None) -> T:
    """Parse a service config whose ``core`` field defaults to the chosen preset."""
    args = list(sys.argv[1:] if argv is None else argv)
    picked, rest = split_preset(args)
    try:
        core = preset(picked["preset"], picked["env"], picked["feature"])  # type: ignore[arg-type]
    except ValueError as e:
        raise SystemExit(str(e)) from e
    default: Any = cls(core=core)  # type: ignore[call-arg]
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
