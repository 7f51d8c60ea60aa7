"""Collector service: one reset-free environment acting with the learner's latest policy.

Consumes: policy weights (``learner/weights``), skills from the repertoire (``repertoire/sample``).
Produces: transition chunks (``collector/transitions/{cid}``), features of safe states
(``collector/features/{cid}``), stats (``collector/stats/{cid}``), a liveliness token.
Run alone:
``python -m services.collector --preset small --collector-id c0 --bus.router tcp/127.0.0.1:7447``
(it acts with its initial policy until weights arrive and keeps a zero skill until the
repertoire answers).
"""

from __future__ import annotations

from services.collector.service import Collector, CollectorArgs
from services.common.cli import serve


def main() -> None:
    serve(CollectorArgs, Collector, lambda a: f"collector/{a.collector_id}", __doc__)


if __name__ == "__main__":
    main()
