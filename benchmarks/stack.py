"""The whole stack on one machine: a router, the repertoire, the learner and two A1 collectors
(``small`` preset, 512 imagination starts × 15 steps per update), for ``--seconds`` after the
learner's first update.

Claims: the rate limiter (``ursa.pace``) holds the learner's replay ratio within 10 % of its
``train_ratio`` without a hand-set pace, while the learner keeps the updates/s of the learner
benchmark at the same work per update, and chunks reach it with a bounded latency. The reference
measured in the same run is the learner alone on synthetic batches (``benchmarks/learner.py``'s
``measure``, same config, same thread count), before the stack starts: ``stack_ratio`` is the
stack's updates/s over it (1.0: the collectors cost the learner nothing).

    .venv/bin/python benchmarks/stack.py [--quick] [--seconds 180] [--actor-grad reinforce]

The last line is ``RESULT updates_per_s=... replay_ratio=... target_ratio=...
chunk_latency_p99_ms=... stack_ratio=...``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from learner import measure  # noqa: E402

from services.stack import Stack, StatsWatcher, wait_for  # noqa: E402
from ursa.config import preset  # noqa: E402
from ursa.threads import limit_threads  # noqa: E402

IMAG_STARTS = 512


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=180.0, help="measured seconds")
    ap.add_argument("--quick", action="store_true", help="60 s instead of --seconds")
    ap.add_argument("--actor-grad", default="dynamics", choices=["dynamics", "reinforce"])
    ap.add_argument(
        "--threads",
        type=int,
        default=0,
        help="the learner's torch threads, in the stack and in the reference "
        "(0: URSA_TORCH_THREADS or 1, the service's default)",
    )
    a = ap.parse_args()
    threads = a.threads or int(os.environ.get("URSA_TORCH_THREADS", "1"))
    # the reference runs with the pools the learner service sets, and the service inherits this
    os.environ["URSA_TORCH_THREADS"] = str(threads)
    limit_threads(torch_threads=threads)
    seconds = 60.0 if a.quick else a.seconds
    cfg = preset("small", "a1")
    lc = dataclasses.replace(cfg.learner, imag_starts=IMAG_STARTS, actor_grad=a.actor_grad)
    ref = measure(lc, 3 if a.quick else 6, 1)["updates_per_s"]
    flags = [
        "--core.learner.imag-starts",
        str(IMAG_STARTS),
        "--core.learner.actor-grad",
        a.actor_grad,
    ]
    with tempfile.TemporaryDirectory() as tmp:
        st = Stack(Path(tmp), run_id="stack", preset="small", env="a1")
        try:
            st.start_training(*flags, collectors=2)
            session = st.session()  # kept: a dropped zenoh session closes
            w = StatsWatcher(session, st.topics)

            def updates() -> float:
                ls = w.get("learner", "main")
                return ls.scalars.get("updates", 0.0) if ls is not None else 0.0

            wait_for(lambda: updates() >= 1, 600, "the learner's first update", every=1.0)
            u0, t0 = updates(), time.monotonic()
            time.sleep(seconds)
            ls = w.get("learner", "main")
            assert ls is not None
            rate = (ls.scalars["updates"] - u0) / (time.monotonic() - t0)
            sc = ls.scalars
            waited = [w.get("collector", f"c{i}") for i in range(2)]
            print(
                f"\nA1, 2 collectors, small preset, {IMAG_STARTS} starts x 15 steps, "
                f"actor {a.actor_grad}, {threads} torch thread(s), {seconds:.0f} s measured"
            )
            print(f"{'':<28}{'value':>10}")
            print(f"{'updates/s (stack)':<28}{rate:>10.3f}")
            print(f"{'updates/s (learner alone)':<28}{ref:>10.3f}")
            print(f"{'replay ratio':<28}{sc['replay_ratio_paced']:>10.2f}")
            print(f"{'target ratio':<28}{sc['train_ratio_limit']:>10.2f}")
            print(f"{'chunk latency p99 (ms)':<28}{sc.get('chunk_latency_p99_ms', -1):>10.1f}")
            for i, c in enumerate(waited):
                if c is not None:
                    print(f"{f'collector c{i} waited (s)':<28}{c.scalars['pace_wait_s']:>10.1f}")
            print(
                f"RESULT updates_per_s={rate:.3f} replay_ratio={sc['replay_ratio_paced']:.2f} "
                f"target_ratio={sc['train_ratio_limit']:.2f} "
                f"chunk_latency_p99_ms={sc.get('chunk_latency_p99_ms', float('nan')):.1f} "
                f"stack_ratio={rate / ref:.2f}"
            )
            w.close()
            session.close()
        finally:
            st.stop_all()


if __name__ == "__main__":
    main()
