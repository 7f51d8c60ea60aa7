"""Learner service: world model + imagination training on every collector's data.

Consumes: transition chunks (``collector/transitions/*``).
Produces: the replay as MCAP segments in ``<run dir>/replay/``, metrics (``learner/stats``),
a liveliness token.
Run alone: ``python -m services.learner --preset small --bus.router tcp/127.0.0.1:7447``
(it waits quietly for data).
"""

from __future__ import annotations

from services.common.cli import serve
from services.learner.service import LearnerArgs, LearnerService


def main() -> None:
    serve(LearnerArgs, LearnerService, "learner", __doc__)


if __name__ == "__main__":
    main()
