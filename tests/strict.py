"""Strict mode (``URSA_STRICT=1``, set by ``.ci/run``): a skipped test is a failed test.

A skip means a part of the system did not run (no chromium, no Docker engine, ...). Outside CI
that is reported with its one-line reason (``-ra``); in strict mode the skip becomes a failure
with the same reason, so a green CI run means every test ran. Deselection (``-m``, ``-k``) is not
a skip and stays allowed. ``xfail`` is untouched (it is not a missing component).
"""

from __future__ import annotations

import os
from collections.abc import Generator
from typing import Any

import pytest

ENV = "URSA_STRICT"


def strict_mode() -> bool:
    """True when ``URSA_STRICT`` is set to anything but empty, ``0``, ``false`` or ``no``."""
    return os.environ.get(ENV, "").strip().lower() not in ("", "0", "false", "no")


def _reason(longrepr: Any) -> str:
    # a skip's longrepr is (path, line, "Skipped: reason")
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def _fail(report: pytest.TestReport | pytest.CollectReport) -> None:
    report.outcome = "failed"
    report.longrepr = f"{ENV}=1: a skip is a failure in strict mode ({_reason(report.longrepr)})"


def pytest_report_header(config: pytest.Config) -> str:
    if strict_mode():
        return f"strict mode ({ENV}=1): every skip fails"
    return f"strict mode off: skips are reported with their reason (set {ENV}=1 to fail them)"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, Any, None]:
    outcome = yield
    report: pytest.TestReport = outcome.get_result()
    if strict_mode() and report.skipped and not hasattr(report, "wasxfail"):
        _fail(report)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Generator[None, Any, None]:
    outcome = yield
    report: pytest.CollectReport = outcome.get_result()
    if strict_mode() and report.skipped:  # a module-level skip or importorskip
        _fail(report)
