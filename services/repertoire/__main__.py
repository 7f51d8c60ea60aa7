"""Repertoire service: the archive of diverse safe skills and its KDE sampler.

Consumes: features of safe states from every collector (``collector/features/*``), encoder
weights from the learner (``learner/encoder``, learned phi only).
Produces: skill samples (query ``repertoire/sample``), snapshots (``repertoire/snapshot``, put
and query), stats, ``<run dir>/repertoire/archive.npz``, a liveliness token.
Run alone: ``python -m services.repertoire --preset small --bus.router tcp/127.0.0.1:7447``;
restarted on the same run directory it restores its archive.
"""

from __future__ import annotations

import signal

from services.common.cli import parse, setup_logging
from services.repertoire.service import RepertoireArgs, RepertoireService


def main() -> None:
    args = parse(RepertoireArgs, description=__doc__)
    setup_logging("repertoire")
    svc = RepertoireService(args)
    signal.signal(signal.SIGTERM, lambda *_: svc.rt.stop.set())
    signal.signal(signal.SIGINT, lambda *_: svc.rt.stop.set())
    try:
        svc.run()
    finally:
        svc.close()


if __name__ == "__main__":
    main()
