"""Per-collector bookkeeping of incoming chunks: order, gaps, duplicates, staleness."""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass
class StreamState:
    """What the learner knows of one collector's stream."""

    incarnation: int = -1
    next_seq: int = 0
    next_step: int = 0
    chunks: int = 0
    steps: int = 0
    gaps: int = 0
    missing_chunks: int = 0
    duplicates: int = 0
    last_policy_version: int = 0
    last_seen: float = 0.0
    """``time.monotonic()`` of the last chunk (duplicates included)."""


@dataclass
class IngestLedger:
    """Classifies each chunk as new, a gap (chunks missing before it) or a duplicate."""

    streams: dict[str, StreamState] = field(default_factory=dict)

    def admit(
        self,
        cid: str,
        incarnation: int,
        seq: int,
        first_step: int,
        n: int,
        policy_version: int,
        now: float | None = None,
    ) -> tuple[bool, bool]:
        """Record a chunk; returns ``(accept, starts_segment)``.

        A chunk of an older incarnation, or with a sequence number already seen, is a duplicate
        (not accepted). A new incarnation or a jump in ``seq`` starts a new replay segment (the
        world model must not link the two across the gap).
        """
        st = self.streams.setdefault(cid, StreamState())
        st.last_seen = time.monotonic() if now is None else now
        if incarnation < st.incarnation or (incarnation == st.incarnation and seq < st.next_seq):
            st.duplicates += 1
            return False, False
        starts = incarnation != st.incarnation or seq != st.next_seq or first_step != st.next_step
        if incarnation == st.incarnation and seq > st.next_seq:
            st.gaps += 1
            st.missing_chunks += seq - st.next_seq
        st.incarnation = incarnation
        st.next_seq = seq + 1
        st.next_step = first_step + n
        st.chunks += 1
        st.steps += n
        st.last_policy_version = policy_version
        return True, starts

    @property
    def total_steps(self) -> int:
        return sum(s.steps for s in self.streams.values())

    def recent(self, within_s: float, now: float | None = None) -> dict[str, StreamState]:
        """The streams that sent a chunk in the last ``within_s`` seconds."""
        now = time.monotonic() if now is None else now
        return {c: s for c, s in self.streams.items() if now - s.last_seen <= within_s}

    def totals(self) -> dict[str, int]:
        """Gaps, missing chunks and duplicates summed over every stream ever seen."""
        return {
            "gaps_total": sum(s.gaps for s in self.streams.values()),
            "missing_total": sum(s.missing_chunks for s in self.streams.values()),
            "duplicates_total": sum(s.duplicates for s in self.streams.values()),
        }
