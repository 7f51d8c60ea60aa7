"""Session-wide fixtures."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import pytest

# URSA_STRICT=1 (CI): a skip fails
pytest_plugins = ["tests.strict", "pytester"]

# The suite's stacks share two cores with background trainings: a learner started by `ursa up`
# (which would take every core beside paced collectors) keeps one torch thread, as every other
# service does, since torch's threads collapse on cores that other processes hold.
os.environ.setdefault("URSA_TORCH_THREADS", "1")


_training: dict[str, Any] = {}


def _root(config: pytest.Config) -> Path:
    cache = os.environ.get("URSA_TRAINED_POINT_DIR")
    if cache:
        return Path(cache)
    base = config._tmp_path_factory.getbasetemp()  # type: ignore[attr-defined]
    return Path(tempfile.mkdtemp(prefix="point-runs-", dir=base))


@pytest.hookimpl(trylast=True)  # after -m/-k deselection: only the tests that will run count
def pytest_collection_modifyitems(
    session: pytest.Session, config: pytest.Config, items: list[pytest.Item]
) -> None:
    """Start the trainings of :mod:`tests.trained` as soon as a collected test needs them: they
    run in the background (at a lowered priority) beside the tests that come before the
    learning tests."""
    if config.option.collectonly:
        return

    def uses(fixture: str) -> bool:
        return any(fixture in getattr(item, "fixturenames", ()) for item in items)

    if uses("point_runs") or uses("a1_cpu_run"):
        from tests.trained import A1_RUN, RUNS, Training

        names = (*(RUNS if uses("point_runs") else ()), *((A1_RUN,) if uses("a1_cpu_run") else ()))
        _training["job"] = Training(_root(config), names)
    # the A1 run trains last in the background: its test goes last, so that every other test
    # runs while it trains
    a1 = [item for item in items if "a1_cpu_run" in getattr(item, "fixturenames", ())]
    if a1:
        items[:] = [item for item in items if item not in a1] + a1


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    job = _training.pop("job", None)
    if job is not None:
        job.cancel()


@pytest.fixture(autouse=True)
def _process_validator() -> Any:
    """Each test starts with the process-wide bus validator of a process that knows no run: a
    service built in-process (API, dashboard) sets it to its run's bounds, which would refuse
    the messages of a later test's run (another env, other widths)."""
    from services.common import bus

    bus.validate_with(None)
    yield
    bus.validate_with(None)


@pytest.fixture(scope="session")
def point_runs(pytestconfig: pytest.Config) -> dict[str, Any]:
    """The trained point-env runs of :mod:`tests.trained` (URSA for each seed and DayDreamer),
    trained once per session in the background from collection on (or reused from
    ``URSA_TRAINED_POINT_DIR``)."""
    from tests.trained import Training

    job = _training.get("job") or Training(_root(pytestconfig))
    _training["job"] = job
    out = job.result()
    print(f"\npoint runs in {job.root}: {out['seconds']} s (cached: {out['cached']})")
    return out


@pytest.fixture(scope="session")
def a1_cpu_run(pytestconfig: pytest.Config) -> Path:
    """The A1 run of the CPU recipe (:data:`tests.trained.A1_RUN`), trained in the background
    after the point runs (or reused from ``URSA_TRAINED_POINT_DIR``)."""
    from tests.trained import A1_RUN, Training

    job = _training.get("job") or Training(_root(pytestconfig))
    _training["job"] = job
    out = job.result((A1_RUN,))
    print(f"\nA1 run in {job.root}: {out['seconds']} s (cached: {out['cached']})")
    path: Path = out["runs"][A1_RUN]
    return path
