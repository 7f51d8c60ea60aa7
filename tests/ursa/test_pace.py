"""The rate limiter's pure pieces (ursa.pace): hand-worked budgets and the collector's gate."""

from __future__ import annotations

import math

import pytest

from ursa.pace import PaceGate, default_slack, insert_budget


def test_insert_budget_hand_worked() -> None:
    # 3200 replayed steps at train_ratio 32 allow 100 inserted steps, half the 10 % tolerance
    # 105, plus 64 steps of slack: 169 allowed, 150 inserted -> 19 more
    assert insert_budget(150, 3200, 32.0, 0.1, 64.0) == pytest.approx(19.0)
    # behind: 200 inserted -> -31, the collectors wait
    assert insert_budget(200, 3200, 32.0, 0.1, 64.0) == pytest.approx(-31.0)
    assert insert_budget(10, 0, 0.0, 0.1, 0.0) == math.inf  # no target: no limit
    # the prefill of 2000 steps is always allowed, then the learner catches up on it
    assert insert_budget(1500, 0, 32.0, 0.1, 64.0, min_inserts=2000) == pytest.approx(500.0)
    assert insert_budget(2000, 0, 32.0, 0.1, 64.0, min_inserts=2000) == pytest.approx(0.0)
    # 2000 * 32 = 64000 samples later: 2100 + 64 allowed
    assert insert_budget(2000, 64000, 32.0, 0.1, 64.0, min_inserts=2000) == pytest.approx(164.0)


def test_default_slack_is_a_few_updates_of_env_steps() -> None:
    # 4 updates of 16 x 64 replayed steps at ratio 32: 4 * 1024 / 32 = 128 env steps
    assert default_slack(16, 64, 32.0) == pytest.approx(128.0)


def test_gate_spends_its_share_then_waits_until_the_budget_rises() -> None:
    gate = PaceGate(mode="wait", allowance=3.0)
    assert gate.open()  # no learner alive: never hold a collector
    gate.learner(True)
    for _ in range(3):  # the live learner has not spoken yet: the prefill allowance
        assert gate.open()
        gate.stepped()
    assert not gate.open()
    gate.hear(total_budget=6.0, collectors=3, engaged=True)
    assert gate.budget == pytest.approx(2.0)  # its share of the 6 steps
    for _ in range(2):
        assert gate.open()
        gate.stepped()
    assert not gate.open()
    gate.hear(total_budget=30.0, collectors=3, engaged=True)
    assert gate.open()


def test_gate_opens_when_the_learner_is_missing_done_or_free() -> None:
    gate = PaceGate(mode="wait", allowance=0.0)
    gate.learner(True)
    gate.hear(total_budget=-100.0, collectors=1, engaged=True)
    assert not gate.open()
    gate.learner(False)
    assert gate.open()  # the learner is gone: its last budget no longer holds anyone
    gate.learner(True)
    assert not gate.open()  # back, but silent: only its allowance (0 here)
    gate.hear(total_budget=-100.0, collectors=1, engaged=False)
    assert gate.open()  # not training (max updates reached, or no repertoire)
    free = PaceGate(mode="free")
    free.learner(True)
    free.hear(total_budget=-100.0, collectors=1, engaged=True)
    assert free.open()  # a real robot never waits
