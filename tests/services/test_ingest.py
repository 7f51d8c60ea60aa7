"""The learner's per-collector ledger: order, gaps, duplicates, and which streams are recent."""

from __future__ import annotations

from services.learner.ingest import IngestLedger
from services.learner.service import LATENCY_WINDOW_S, latency_stats


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


def test_chunk_latency_covers_only_the_last_window() -> None:
    # a start-up backlog (5 chunks sent 4 s late, received at t = 0..4) and then 100 chunks of
    # 10..109 ms: once the backlog is older than the window only the steady state counts
    backlog = [(float(t), 4.0) for t in range(5)]
    steady = [(10.0 + t, (10 + t) / 1e3) for t in range(100)]
    lat = backlog + steady
    assert LATENCY_WINDOW_S == 60.0
    early = latency_stats([x for x in lat if x[0] <= 30.0], now=30.0)  # backlog + 21 steady
    assert early["chunk_latency_n"] == 26 and early["chunk_latency_p99_ms"] == 4000.0
    late = latency_stats(lat, now=109.0)  # chunks received at 49..109 s: latencies 49..109 ms
    assert late["chunk_latency_n"] == 61
    assert late["chunk_latency_p50_ms"] == 79.0
    assert abs(late["chunk_latency_p99_ms"] - (49 + 0.99 * 60)) < 1e-9
    assert latency_stats(lat, now=1000.0) == {}
