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

from services.common.cli import serve
from services.evaluator.service import Evaluator, EvaluatorArgs


def main() -> None:
    serve(EvaluatorArgs, Evaluator, lambda a: f"evaluator/{a.collector_id}", __doc__)


if __name__ == "__main__":
    main()
