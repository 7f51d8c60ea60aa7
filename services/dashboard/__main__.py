"""Dashboard service: the live viser web page of a run.

Consumes: stats of every service (``*/stats/**``), liveliness tokens, repertoire snapshots.
Produces: a web page (default http://127.0.0.1:8080), a liveliness token.
Run alone: ``python -m services.dashboard --port 8080 --bus.router tcp/127.0.0.1:7447``
(it shows "no data yet" until services publish).
"""

from __future__ import annotations

from services.common.cli import serve
from services.dashboard.service import Dashboard, DashboardArgs


def main() -> None:
    serve(DashboardArgs, Dashboard, "dashboard", __doc__)


if __name__ == "__main__":
    main()
