"""Dashboard service: the live viser web page of a run.

Consumes: stats of every service (``*/stats/**``), liveliness tokens, repertoire snapshots.
Produces: a web page (default http://127.0.0.1:8080), a liveliness token.
Run alone: ``python -m services.dashboard --port 8080 --bus.router tcp/127.0.0.1:7447``
(it shows "no data yet" until services publish).
"""

from __future__ import annotations

import signal

from services.common.cli import parse, setup_logging
from services.dashboard.service import Dashboard, DashboardArgs


def main() -> None:
    args = parse(DashboardArgs, description=__doc__)
    setup_logging("dashboard")
    d = Dashboard(args)
    signal.signal(signal.SIGTERM, lambda *_: d.rt.stop.set())
    signal.signal(signal.SIGINT, lambda *_: d.rt.stop.set())
    try:
        d.run()
    finally:
        d.close()


if __name__ == "__main__":
    main()
