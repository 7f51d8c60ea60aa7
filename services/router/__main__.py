"""The URSA Zenoh router: the Python zenoh package opened in ``router`` mode.

Consumes nothing and produces nothing itself; it relays every key between the client sessions
of the other services. With authentication on (``--auth on``, or ``auto`` with a non-loopback
``--listen`` or existing run secrets), clients log in with the user/password of their role and
the run's access rules (services/common/secrets.py) say who may publish what; missing secrets
are generated under ``<run dir>/secrets``. Run alone:
``python -m services.router --listen tcp/0.0.0.0:7447 --run.run-id myrun``.
"""

from __future__ import annotations

import logging
import signal
import threading
from dataclasses import dataclass, field
from typing import Annotated

import tyro
import zenoh

from services.common.bus import router_config
from services.common.config import BusConfig, RunConfig
from services.common.secrets import router_auth

log = logging.getLogger("router")


@dataclass(frozen=True)
class RouterArgs:
    """The router: where it listens, and the run whose secrets and access rules it uses."""

    bus: Annotated[BusConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)


def main(args: RouterArgs) -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.try_init_log_from_env()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    auth = router_auth(args.bus, args.run)
    with zenoh.open(router_config(args.bus, auth)) as session:
        log.info(
            "router %s listening on %s, authentication %s",
            session.zid(),
            args.bus.listen,
            f"on ({auth.dictionary})" if auth else "off",
        )
        print(f"ROUTER READY {args.bus.listen}", flush=True)
        stop.wait()
    log.info("router stopped")


if __name__ == "__main__":
    main(tyro.cli(RouterArgs))
