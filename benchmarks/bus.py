"""The bus under load: N collectors publishing at full speed to one learner through the router.

Real processes on loopback: a router, a learner that only ingests (it never trains here), and N
real collectors stepping their environment as fast as they can. Reports the fraction of chunks
the learner received (target 1.0), the p99 chunk latency from send stamp to receipt, and the
learner's maximum ingest rate (decode + ledger + replay + MCAP write, timed in-process on the
chunks of this run) against the rate the collectors produced (target headroom ≥ 10×).

    .venv/bin/python benchmarks/bus.py [--quick] [--collectors 4] [--seconds 60] [--env point]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from proto import codec  # noqa: E402
from proto import ursa_pb2 as pb  # noqa: E402
from services.common.config import RunConfig  # noqa: E402
from services.learner.replay_store import read_all  # noqa: E402
from services.learner.service import LearnerArgs, LearnerService  # noqa: E402
from services.stack import Stack, StatsWatcher, wait_for  # noqa: E402
from ursa.config import preset  # noqa: E402


def max_ingest(stack: Stack, replay_dir: Path, env: str) -> tuple[float, int]:
    """Chunks/s and steps/chunk of the learner's ingest path on this run's chunks."""
    payloads = [codec.encode(c) for c in read_all(replay_dir)]
    with tempfile.TemporaryDirectory() as tmp:
        args = LearnerArgs(
            core=preset("tiny", env),  # type: ignore[arg-type]
            bus=stack.bus,
            run=RunConfig("ingest", Path(tmp)),
            min_replay=10**12,
        )
        svc = LearnerService(args)
        t0 = time.perf_counter()
        for p in payloads:
            svc._on_chunk(codec.decode(pb.TransitionChunk, p), "bench")
        svc.drain()
        dt = time.perf_counter() - t0
        svc.close()
    steps = int(codec.decode(pb.TransitionChunk, payloads[0]).obs.shape[0]) if payloads else 0
    return len(payloads) / dt, steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="20 s of load instead of 60")
    ap.add_argument("--collectors", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument(
        "--env",
        default="a1",
        choices=["a1", "point"],
        help="a1: the real workload; point: a stress test (~20x more steps/s)",
    )
    a = ap.parse_args()
    seconds = 20.0 if a.quick else a.seconds
    with tempfile.TemporaryDirectory() as tmp:
        st = Stack(Path(tmp), run_id="bus", preset="tiny", env=a.env)
        try:
            st.start_router()
            st.start("learner", "services.learner", "--min-replay", str(10**12))
            session = st.session()
            w = StatsWatcher(session, st.topics)
            wait_for(lambda: w.get("learner", "main"), 60, "the learner")
            cids = [f"b{i}" for i in range(a.collectors)]
            for i, cid in enumerate(cids):
                st.start(cid, "services.collector", "--collector-id", cid, "--seed", str(i))
            wait_for(lambda: all(w.get("collector", c) for c in cids), 60, "the collectors")

            def scal(service: str, sid: str) -> Any:
                msg = w.get(service, sid)
                assert msg is not None, (service, sid)
                return msg.scalars

            steps0 = sum(int(scal("collector", c)["steps"]) for c in cids)
            t0 = time.monotonic()
            time.sleep(seconds)
            produced_steps = sum(int(scal("collector", c)["steps"]) for c in cids)
            elapsed = time.monotonic() - t0
            produced_steps -= steps0
            for cid in cids:  # SIGTERM: each publishes its last partial chunk and stats
                st.procs[cid].kill(15)
            for cid in cids:
                st.procs[cid].stop()

            def settled() -> bool:
                ls = w.get("learner", "main")
                if ls is None:
                    return False
                return (
                    all(
                        ls.scalars.get(f"chunks/{c}", 0) >= scal("collector", c)["chunks"]
                        for c in cids
                    )
                    and ls.scalars["inbox"] == 0
                )

            try:
                wait_for(settled, 30, "the learner to catch up")
            except TimeoutError:
                pass
            time.sleep(1.0)
            ls = w.get("learner", "main")
            assert ls is not None
            sent = {c: int(scal("collector", c)["chunks"]) for c in cids}
            got = {c: int(ls.scalars.get(f"chunks/{c}", 0)) for c in cids}
            p99 = ls.scalars.get("chunk_latency_p99_ms", float("nan"))
            p50 = ls.scalars.get("chunk_latency_p50_ms", float("nan"))
            w.close()
            session.close()
            st.procs["learner"].stop()
            ingest_cps, steps_per_chunk = max_ingest(st, st.run_dir / "replay", a.env)
        finally:
            st.stop_all()
    delivered = sum(got.values()) / max(sum(sent.values()), 1)
    produced_sps = produced_steps / elapsed
    headroom = ingest_cps * steps_per_chunk / max(produced_sps, 1e-9)
    print(f"{'collector':<10}{'sent':>10}{'received':>10}")
    for c in cids:
        print(f"{c:<10}{sent[c]:>10}{got[c]:>10}")
    print(
        json.dumps(
            {
                "env": a.env,
                "collectors": a.collectors,
                "seconds": round(elapsed, 1),
                "produced_steps_per_s": round(produced_sps, 1),
                "max_ingest_steps_per_s": round(ingest_cps * steps_per_chunk, 1),
                "latency_p50_ms": round(p50, 2),
                "latency_p99_ms": round(p99, 2),
            }
        )
    )
    print(f"RESULT delivered={delivered:.4f} p99_ms={p99:.2f} ingest_headroom={headroom:.2f}")


if __name__ == "__main__":
    main()
