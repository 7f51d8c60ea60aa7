"""Command-line helpers shared by services: presets, logging, and the one entry point
(:func:`serve`) every service's ``__main__`` calls."""

from __future__ import annotations

import errno
import logging
import os
import signal
import sys
import typing
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

import tyro

from ursa.config import PresetName, preset
from ursa.threads import limit_threads

T = TypeVar("T")
PRESETS: tuple[PresetName, ...] = typing.get_args(PresetName)


# ``--core.feature`` is the field's own flag: parsed by tyro as a plain field it would change
# the feature without the skill dimensions that follow from it (the repertoire then crashed on
# its bounds and the learner dropped every chunk), so it is the same picker as ``--feature``.
_PICKERS = {
    "--preset": "preset",
    "--env": "env",
    "--feature": "feature",
    "--core.feature": "feature",
}


def split_preset(argv: Sequence[str]) -> tuple[dict[str, str | None], list[str]]:
    """Take ``--preset``, ``--env`` and ``--feature`` (alias ``--core.feature``) out of argv:
    they pick the defaults of every other field (env vars URSA_PRESET, URSA_ENV,
    URSA_FEATURE)."""
    picked: dict[str, str | None] = {
        "preset": os.environ.get("URSA_PRESET", "cpu"),
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
            picked[_PICKERS[flag]] = val
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


class Service(Protocol):
    """What :func:`serve` runs: a service whose runtime's ``stop`` event ends ``run``."""

    @property
    def rt(self) -> Any: ...

    def run(self) -> None: ...

    def close(self) -> None: ...


A = TypeVar("A")


def serve(
    args_type: type[A],
    build: Callable[[A], Service],
    name: str | Callable[[A], str],
    description: str | None,
    signals: bool = True,
) -> None:
    """The entry point of every service: parse its args (``--preset``/``--env``/``--feature``
    first), set up logging as ``name``, set its thread pools
    (:func:`ursa.threads.limit_threads`: 1 each, the learner's torch threads from
    ``--torch-threads``), build it, stop it on SIGTERM/SIGINT (``signals=False`` where the
    service's server installs its own handlers), run it, and close it however run ends. A
    service that cannot start because its run directory's volume is full says so in one line
    instead of a traceback."""
    args = parse(args_type, description=description)
    log = setup_logging(name(args) if callable(name) else name)
    # before anything spins up a pool; the learner's torch threads come from its args
    log.info("threads: %s", limit_threads(torch_threads=getattr(args, "torch_threads", 1)))
    try:
        svc = build(args)
    except OSError as e:
        if e.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        run = getattr(args, "run", None)
        log.critical(
            "cannot start: run directory %s is full (%s); free space on its volume",
            getattr(run, "dir", "?"),
            e,
        )
        raise SystemExit(1) from None
    if signals:
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: svc.rt.stop.set())
    try:
        svc.run()
    finally:
        svc.close()
