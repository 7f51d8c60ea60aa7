"""Strict mode (tests/strict.py): with URSA_STRICT=1 every skip, in a test or at collection,
fails; without it skips stay skips with their reason; deselection and xfail are unaffected."""

from __future__ import annotations

import pytest

INNER = """
import pytest

def test_runs():
    pass  # a passing inner test: strict mode must leave it passing

def test_skips_in_body():
    pytest.skip("no chromium here")

@pytest.mark.skipif(True, reason="no docker engine")
def test_skipif_marker():
    pass

@pytest.mark.xfail(reason="known", strict=True)
def test_xfails():
    assert False

@pytest.mark.slow
def test_deselected():
    pass
"""
MODULE_SKIP = 'import pytest\npytest.importorskip("no_such_module_ursa")\n\ndef test_x(): pass\n'


def _run(
    pytester: pytest.Pytester, strict: str | None, monkeypatch: pytest.MonkeyPatch
) -> pytest.RunResult:
    if strict is None:
        monkeypatch.delenv("URSA_STRICT", raising=False)
    else:
        monkeypatch.setenv("URSA_STRICT", strict)
    pytester.makepyfile(test_inner=INNER, test_module_skip=MODULE_SKIP)
    pytester.makeini("[pytest]\nmarkers =\n    slow: slow\n")
    return pytester.runpytest_inprocess(
        "-p", "tests.strict", "-ra", "-m", "not slow", "--continue-on-collection-errors"
    )


def test_strict_mode_turns_every_skip_into_a_failure(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    res = _run(pytester, "1", monkeypatch)
    # the skipif marker skips in setup: its failure is an error; the module skip one too
    res.assert_outcomes(passed=1, failed=1, xfailed=1, deselected=1, errors=2)
    out = res.stdout.str()
    assert "strict mode (URSA_STRICT=1): every skip fails" in out
    assert "a skip is a failure in strict mode (Skipped: no chromium here)" in out
    assert "a skip is a failure in strict mode (Skipped: no docker engine)" in out
    assert "no_such_module_ursa" in out
    assert res.ret != 0


@pytest.mark.parametrize("value", [None, "0", ""])
def test_without_strict_mode_skips_stay_with_their_reason(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, value: str | None
) -> None:
    res = _run(pytester, value, monkeypatch)
    res.assert_outcomes(passed=1, skipped=3, xfailed=1, deselected=1)
    out = res.stdout.str()
    assert "SKIPPED [1] test_inner.py:7: no chromium here" in out
    assert "no docker engine" in out and "could not import 'no_such_module_ursa'" in out
    assert res.ret == 0
