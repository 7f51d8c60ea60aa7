"""Evaluator service: an evaluation collector that runs one skill on request.

Consumes: evaluation queries (``evaluator/evaluate``: EvaluateRequest -> EvaluateReply), the
learner's policy weights (``learner/weights``), repertoire snapshots (``repertoire/snapshot``).
Produces: replies with the achieved features, distance, δ, return and unsafe steps; stats
(``evaluator/stats``); a liveliness token (``alive/evaluator/{id}``). It feeds no replay and no
repertoire.
Run alone: ``python -m services.evaluator --preset tiny --env point --collector-id eval
--bus.router tcp/127.0.0.1:7447`` (it acts like a collector before the first weights: uniformly
at random; it answers "unavailable" until a repertoire snapshot exists).
"""

from __future__ import annotations

import signal

from services.common.cli import parse, setup_logging
from services.evaluator.service import Evaluator, EvaluatorArgs


def main() -> None:
    args = parse(EvaluatorArgs, description=__doc__)
    setup_logging(f"evaluator/{args.collector_id}")
    ev = Evaluator(args)
    signal.signal(signal.SIGTERM, lambda *_: ev.rt.stop.set())
    signal.signal(signal.SIGINT, lambda *_: ev.rt.stop.set())
    try:
        ev.run()
    finally:
        ev.close()


if __name__ == "__main__":
    main()
