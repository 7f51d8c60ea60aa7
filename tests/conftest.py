"""Session-wide fixtures."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

# URSA_STRICT=1 (CI): a skip fails
pytest_plugins = ["tests.strict", "pytester"]


@pytest.fixture(scope="session")
def point_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The trained point-env runs of :mod:`tests.trained` (URSA and DayDreamer), trained once
    per session (or reused from ``URSA_TRAINED_POINT_DIR``)."""
    from tests.trained import trained_point_runs

    cache = os.environ.get("URSA_TRAINED_POINT_DIR")
    root = Path(cache) if cache else tmp_path_factory.mktemp("point-runs")
    out = trained_point_runs(root)
    print(f"\npoint runs in {root}: {out['seconds']} s (cached: {out['cached']})")
    return out
