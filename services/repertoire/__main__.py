"""Repertoire service: the archive of diverse safe skills and its KDE sampler.

Consumes: features of safe states from every collector (``collector/features/*``), encoder
weights from the learner (``learner/encoder``, learned phi only).
Produces: skill samples (query ``repertoire/sample``), snapshots (``repertoire/snapshot``, put
and query), stats, ``<run dir>/repertoire/archive.npz``, a liveliness token.
Run alone: ``python -m services.repertoire --preset small --bus.router tcp/127.0.0.1:7447``;
restarted on the same run directory it restores its archive.
"""

from __future__ import annotations

from services.common.cli import serve
from services.repertoire.service import RepertoireArgs, RepertoireService


def main() -> None:
    serve(RepertoireArgs, RepertoireService, "repertoire", __doc__)


if __name__ == "__main__":
    main()
