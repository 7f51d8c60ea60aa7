from __future__ import annotations

import pytest

from proto.topics import Topics


def test_keys_have_the_documented_shape() -> None:
    t = Topics("run-1")
    assert t.transitions("c0") == "ursa/run-1/collector/transitions/c0"
    assert t.transitions() == "ursa/run-1/collector/transitions/*"
    assert t.features("c1") == "ursa/run-1/collector/features/c1"
    assert t.collector_stats("c1") == "ursa/run-1/collector/stats/c1"
    assert t.sample == "ursa/run-1/repertoire/sample"
    assert t.snapshot == "ursa/run-1/repertoire/snapshot"
    assert t.weights == "ursa/run-1/learner/weights"
    assert t.encoder == "ursa/run-1/learner/encoder"
    assert t.stats("learner") == "ursa/run-1/learner/stats"
    assert t.evaluate == "ursa/run-1/evaluator/evaluate"
    assert t.alive("collector", "c0") == "ursa/run-1/alive/collector/c0"
    assert t.parse_alive("ursa/run-1/alive/collector/c0") == ("collector", "c0")
    assert t.parse_alive("ursa/other/alive/collector/c0") is None


@pytest.mark.parametrize("bad", ["", "a/b", "a b", "*", "x?"])
def test_bad_chunks_are_refused(bad: str) -> None:
    with pytest.raises(ValueError):
        Topics(bad)
    if bad != "*":  # "*" is the wildcard for ids, never a run id
        with pytest.raises(ValueError):
            Topics("ok").transitions(bad)
