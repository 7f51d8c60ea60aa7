"""Learner service: world model + imagination training on every collector's data.

Consumes: transition chunks (``collector/transitions/*``).
Produces: the replay as MCAP segments in ``<run dir>/replay/``, metrics (``learner/stats``),
a liveliness token.
Run alone: ``python -m services.learner --preset small --bus.router tcp/127.0.0.1:7447``
(it waits quietly for data).
"""

from __future__ import annotations

import errno
import logging
import signal

from services.common.cli import parse, setup_logging
from services.learner.service import LearnerArgs, LearnerService


def main() -> None:
    args = parse(LearnerArgs, description=__doc__)
    setup_logging("learner")
    try:
        svc = LearnerService(args)
    except OSError as e:
        if e.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        # a restart on a full run volume: say so in one line, not a traceback
        logging.getLogger("learner").critical(
            "cannot start: run directory %s is full (%s); free space on its volume",
            args.run.dir,
            e,
        )
        raise SystemExit(1) from None
    signal.signal(signal.SIGTERM, lambda *_: svc.rt.stop.set())
    signal.signal(signal.SIGINT, lambda *_: svc.rt.stop.set())
    try:
        svc.run()
    finally:
        svc.close()


if __name__ == "__main__":
    main()
