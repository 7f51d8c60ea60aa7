"""Samples-per-insert rate limiting between collectors and the learner (as Reverb's
``SampleToInsertRatio`` and DreamerV3's embodied ``train_ratio``), as pure pieces.

The learner's replay ratio is ``samples / inserted`` (replayed steps per collected env step);
its target is ``LearnerConfig.train_ratio``. Simulated collectors outrun a CPU learner by two
orders of magnitude, so without a limit almost none of their data is ever replayed. The learner
computes how many more env steps the collectors may insert before the ratio falls more than
``tolerance`` below its target (:func:`insert_budget`) and publishes it with the number of
collectors alive; each collector spends its share step by step (:class:`PaceGate`) and waits
when it is spent, until the learner's next message raises it.

- ``mode="wait"`` (simulation): collectors wait when the budget is spent.
- ``mode="free"`` (a real robot, which cannot pause): collectors never wait; the learner then
  reports the ratio it reaches.
- The learner's prefill is collected at full speed; from the learner process's first update on,
  the ratio is held over the steps inserted and sampled since then (the learner passes those
  counts), so data that arrived while no learner trained is not owed. A learner that is done
  (``--max-updates``), cannot train (no repertoire snapshot after its prefill) or is missing
  (no liveliness token) never holds a collector: the gate opens, and the collector keeps its
  bounded backlog as without a limiter.

The budget is a function of the learner's counters, which its checkpoint and replay restore,
so the limit resumes where it stopped after a restart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

PaceMode = Literal["wait", "free"]


def insert_budget(
    inserted: int,
    samples: int,
    train_ratio: float,
    tolerance: float,
    slack: float,
    min_inserts: int = 0,
) -> float:
    """Env steps that may still be inserted before ``samples / inserted`` falls below
    ``train_ratio / (1 + tolerance / 2)``, plus ``slack`` steps (what the learner consumes in a few
    updates, so that collectors run while it trains); negative when the learner is behind.

    The first ``min_inserts`` steps (the learner's prefill) are always allowed; as with
    Reverb's ``min_size_to_sample``, the learner then catches up on them before collectors go
    on, so that the ratio holds over the whole run."""
    if train_ratio <= 0:
        return math.inf
    # half the tolerance is the limiter's own; the other half absorbs the chunks in flight
    # (published before the collectors heard the budget, ingested after it was computed)
    allowed = samples / train_ratio * (1.0 + 0.5 * tolerance) + slack
    return max(float(min_inserts), allowed) - inserted


def default_slack(batch_size: int, seq_len: int, train_ratio: float, updates: int = 4) -> float:
    """Env steps worth ``updates`` learner updates of B × T replayed steps each."""
    return updates * batch_size * seq_len / max(train_ratio, 1e-9)


@dataclass
class PaceGate:
    """A collector's side of the limiter: the latest budget share, counted down per step.

    It holds the collector only while a learner is alive (its liveliness token): a missing
    learner never holds it. Until the live learner's first budget arrives (it is still starting),
    the collector may take ``allowance`` steps, its share of the learner's prefill.
    """

    mode: PaceMode = "wait"
    allowance: float = 2000.0
    """Steps allowed before a live learner's first budget is heard."""
    budget: float = math.inf
    """Env steps this collector may still take."""
    heard: bool = False
    """A budget has arrived from the live learner."""
    learner_alive: bool = False
    waited_s: float = 0.0
    """Seconds spent waiting so far."""

    def __post_init__(self) -> None:
        self.budget = self.allowance

    def hear(self, total_budget: float, collectors: int, engaged: bool) -> None:
        """A budget from the learner: ``total_budget`` for all ``collectors`` alive;
        ``engaged`` False (done, or unable to train) lifts the limit."""
        self.heard = True
        self.budget = total_budget / max(1, collectors) if engaged else math.inf

    def learner(self, alive: bool) -> None:
        """The learner's liveliness changed (a restarted learner starts from its allowance
        again until its first budget)."""
        if alive and not self.learner_alive and not self.heard:
            self.budget = self.allowance
        if not alive:
            self.heard = False
        self.learner_alive = alive

    def open(self) -> bool:
        """Whether the collector may take a step now."""
        if self.mode == "free" or not self.learner_alive:
            return True
        return self.budget > 0

    def stepped(self) -> None:
        """Spend one step of the budget."""
        self.budget -= 1.0
