"""Small run directories made in-process with the SerialLoop, cached per session."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.ursa.eval._runs import make_run
from ursa.config import Config


@pytest.fixture(scope="session")
def run_factory(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """make(name, cfg, steps, prefill) -> run dir, cached per session."""
    root = tmp_path_factory.mktemp("runs")
    cache: dict[str, Path] = {}

    def make(name: str, cfg: Config, steps: int, prefill: int) -> Path:
        if name not in cache:
            cache[name] = make_run(root, name, cfg, steps, prefill)
        return cache[name]

    return make
