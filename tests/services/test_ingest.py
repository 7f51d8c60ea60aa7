"""The learner's per-collector ledger: order, gaps, duplicates, and which streams are recent."""

from __future__ import annotations

from services.learner.ingest import IngestLedger


def test_gaps_duplicates_and_new_incarnations() -> None:
    led = IngestLedger()
    assert led.admit("c0", 0, 0, 0, 50, 1, now=0.0) == (True, True)  # first chunk: new segment
    assert led.admit("c0", 0, 1, 50, 50, 1, now=1.0) == (True, False)
    assert led.admit("c0", 0, 1, 50, 50, 1, now=2.0) == (False, False)  # seen: duplicate
    assert led.admit("c0", 0, 4, 200, 50, 2, now=3.0) == (True, True)  # 2 and 3 lost: a gap
    assert led.admit("c0", 1, 0, 0, 50, 2, now=4.0) == (True, True)  # restarted collector
    assert led.admit("c0", 0, 5, 250, 50, 2, now=5.0) == (False, False)  # old incarnation
    st = led.streams["c0"]
    assert (st.chunks, st.steps, st.gaps, st.missing_chunks, st.duplicates) == (4, 200, 1, 2, 2)
    assert led.totals() == {"gaps_total": 1, "missing_total": 2, "duplicates_total": 2}


def test_recent_streams_forget_collectors_that_left() -> None:
    led = IngestLedger()
    led.admit("old", 0, 0, 0, 10, 0, now=0.0)
    led.admit("new", 0, 0, 0, 10, 0, now=500.0)
    led.admit("old", 0, 0, 0, 10, 0, now=550.0)  # a duplicate still counts as heard from
    assert set(led.recent(100.0, now=600.0)) == {"old", "new"}
    assert set(led.recent(60.0, now=600.0)) == {"old"}
    assert set(led.recent(10.0, now=1000.0)) == set()
    assert led.total_steps == 20  # forgetting a stream in the stats keeps its data
