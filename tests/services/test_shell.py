"""The one service entry point (services.common.cli.serve): stop on SIGTERM, close however run
ends, and a full run volume at start-up reported in one line instead of a traceback."""

from __future__ import annotations

import errno
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest

from services.common.cli import serve
from services.common.config import RunConfig
from ursa.config import Config


@dataclass(frozen=True)
class _Args:
    core: Config = field(default_factory=Config)
    run: RunConfig = field(default_factory=RunConfig)
    name: str = "x"


class _Runtime:
    def __init__(self) -> None:
        self.stop = threading.Event()


class _Service:
    instances: list[_Service] = []  # noqa: RUF012 - the test's record of what was built

    def __init__(self, args: _Args) -> None:
        self.args = args
        self.rt = _Runtime()
        self.closed = False
        self.instances.append(self)

    def run(self) -> None:
        threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM)).start()
        assert self.rt.stop.wait(10.0), "SIGTERM did not stop the service"

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def argv(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setattr(sys, "argv", ["svc", "--preset", "tiny", "--env", "point", "--name", "y"])
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    yield
    for s, h in old.items():
        signal.signal(s, h)


@pytest.mark.usefixtures("argv")
def test_serve_parses_runs_until_sigterm_and_closes() -> None:
    _Service.instances.clear()
    serve(_Args, _Service, lambda a: f"svc/{a.name}", "a test service")
    (svc,) = _Service.instances
    assert svc.args.name == "y" and svc.args.core.env == "point"
    assert svc.rt.stop.is_set() and svc.closed


@pytest.mark.usefixtures("argv")
def test_serve_closes_when_run_raises() -> None:
    class Failing(_Service):
        def run(self) -> None:
            raise RuntimeError("boom")

    _Service.instances.clear()
    with pytest.raises(RuntimeError, match="boom"):
        serve(_Args, Failing, "svc", None)
    assert _Service.instances[0].closed


@pytest.mark.usefixtures("argv")
def test_a_full_run_volume_at_start_is_one_line(caplog: pytest.LogCaptureFixture) -> None:
    def full(args: _Args) -> _Service:
        raise OSError(errno.ENOSPC, "No space left on device")

    with caplog.at_level(logging.CRITICAL), pytest.raises(SystemExit) as e:
        serve(_Args, full, "svc", None)
    assert e.value.code == 1
    assert any("is full" in r.getMessage() for r in caplog.records), caplog.records

    def denied(args: _Args) -> _Service:
        raise OSError(errno.EACCES, "Permission denied")

    with pytest.raises(PermissionError):  # any other OSError is not hidden
        serve(_Args, denied, "svc", None)
