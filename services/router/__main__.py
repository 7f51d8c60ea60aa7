"""The URSA Zenoh router: the Python zenoh package opened in ``router`` mode.

Consumes nothing and produces nothing itself; it relays every key between the client sessions
of the other services. Run alone: ``python -m services.router --bus.listen tcp/0.0.0.0:7447``.
"""

from __future__ import annotations

import logging
import signal
import threading

import tyro
import zenoh

from services.common.bus import router_config
from services.common.config import BusConfig

log = logging.getLogger("router")


def main(bus: BusConfig) -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.try_init_log_from_env()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    with zenoh.open(router_config(bus)) as session:
        log.info("router %s listening on %s", session.zid(), bus.listen)
        print(f"ROUTER READY {bus.listen}", flush=True)
        stop.wait()
    log.info("router stopped")


if __name__ == "__main__":
    main(tyro.cli(BusConfig))
