"""The URSA Zenoh router: the Python zenoh package opened in ``router`` mode.

Consumes nothing and produces nothing itself; it relays every key between the client sessions
of the other services. With authentication on (``--auth on``, or ``auto`` with a non-loopback
``--listen`` or existing run secrets), clients log in with the user/password of their role and
the run's access rules (services/common/secrets.py) say who may publish what; missing secrets
are generated under ``<run dir>/secrets``. Run alone:
``python -m services.router --listen tcp/0.0.0.0:7447 --run.run-id myrun``.

A second router (collectors on another machine): ``--connect tcp/<main>:7447`` bridges its own
clients to the main router; with authentication on it needs a copy of the main run's
``secrets/`` directory (it logs in as ``bridge`` and recognises the main router by its id).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
from dataclasses import dataclass, field
from typing import Annotated

import tyro
import zenoh

from services.common import secrets
from services.common.bus import router_config
from services.common.config import BusConfig, RunConfig
from services.common.secrets import router_auth

log = logging.getLogger("router")


@dataclass(frozen=True)
class RouterArgs:
    """The router: where it listens, and the run whose secrets and access rules it uses."""

    bus: Annotated[BusConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)
    connect: str = os.environ.get("URSA_ROUTER_CONNECT", "")
    """Endpoints of a main router to bridge to, comma-separated (env URSA_ROUTER_CONNECT);
    empty: this is the main router."""


def bridged_config(args: RouterArgs, auth: secrets.RouterAuth | None) -> zenoh.Config:
    """The router's zenoh config: the main router (its id fixed by the run's secrets), or a
    second one connected to it (``connect``)."""
    conf = router_config(args.bus, auth)
    upstream = [e.strip() for e in args.connect.split(",") if e.strip()]
    if auth is None:
        if upstream:
            conf.insert_json5("connect/endpoints", json.dumps(upstream))
        return conf
    d = auth.dictionary.parent
    if not upstream:
        conf.insert_json5("id", json.dumps(secrets.read_router_zid(d)))
        return conf
    try:
        creds = secrets.read_credentials(d / f"{secrets.BRIDGE}.cred")
        zid = secrets.read_router_zid(d)
    except (OSError, ValueError) as e:
        raise SystemExit(
            f"a second router needs the main run's secrets ({e}): copy <run>/secrets from the "
            "main machine into this run directory (or --bus.secrets DIR)"
        ) from e
    conf.insert_json5("connect/endpoints", json.dumps(upstream))
    conf.insert_json5("transport/auth/usrpwd/user", json.dumps(creds.user))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(creds.password))
    conf.insert_json5("access_control", json.dumps(secrets.access_control(auth.run_id, zid)))
    return conf


def main(args: RouterArgs) -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    zenoh.try_init_log_from_env()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    d = secrets.secrets_dir(args.bus, args.run)
    missing = d is None or not (d / secrets.USERS_FILE).exists()
    auth_on = args.bus.auth == "on" or (
        args.bus.auth == "auto" and not secrets.is_loopback(args.bus.listen)
    )
    if args.connect and missing and auth_on:
        # never generate secrets of its own: they would not be the main router's
        raise SystemExit(
            f"a second router (--connect {args.connect}) with authentication on needs a "
            f"copy of the main run's secrets in {d}"
        )
    auth = router_auth(args.bus, args.run)
    with zenoh.open(bridged_config(args, auth)) as session:
        log.info(
            "router %s listening on %s%s, authentication %s",
            session.zid(),
            args.bus.listen,
            f", bridged to {args.connect}" if args.connect else "",
            f"on ({auth.dictionary})" if auth else "off",
        )
        print(f"ROUTER READY {args.bus.listen}", flush=True)
        stop.wait()
    log.info("router stopped")


if __name__ == "__main__":
    main(tyro.cli(RouterArgs))
