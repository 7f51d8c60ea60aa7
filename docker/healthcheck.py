"""Container health checks of the URSA image (compose.yaml's ``healthcheck``); exit 0 = healthy.

  healthcheck.py tcp [HOST:PORT]      something accepts TCP there (default: the router's port
                                      from URSA_ROUTER_LISTEN, on 127.0.0.1) - the router
  healthcheck.py http URL             GET URL answers 2xx/3xx - the API and the dashboard
  healthcheck.py alive SERVICE [ID]   the router knows the liveliness token
                                      ``ursa/{run}/alive/{SERVICE}/{ID}``: the service is up *and*
                                      on the bus. ID defaults to this container's own collector
                                      id for collectors (URSA_COLLECTOR_ID, else the host name,
                                      as the collector computes it) and to ``*`` otherwise.

Standard library only, except ``alive`` (the zenoh package the services use). Each check opens
and closes its own connection within a few seconds.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import urllib.error
import urllib.request

TIMEOUT_S = float(os.environ.get("URSA_HEALTHCHECK_TIMEOUT_S", "4"))


def check_tcp(target: str | None) -> str:
    if target is None:
        listen = os.environ.get("URSA_ROUTER_LISTEN", "tcp/0.0.0.0:7447")
        target = f"127.0.0.1:{listen.rsplit(':', 1)[-1]}"
    host, port = target.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=TIMEOUT_S):
        return f"tcp {target} open"


def check_http(url: str) -> str:
    with urllib.request.urlopen(url, timeout=TIMEOUT_S) as r:
        return f"http {url} -> {r.status}"


def own_collector_id() -> str:
    # the same rule as services.collector.service.default_collector_id (kept import-free: that
    # module pulls in numpy and the simulator)
    cid = os.environ.get("URSA_COLLECTOR_ID") or os.uname().nodename
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in cid)


def check_alive(service: str, sid: str | None) -> str:
    import zenoh

    if sid is None:
        sid = own_collector_id() if service == "collector" else "*"
    run = os.environ.get("URSA_RUN_ID", "default")
    router = os.environ.get("URSA_ROUTER", "tcp/router:7447")
    key = f"ursa/{run}/alive/{service}/{sid}"
    conf = zenoh.Config()
    # with authentication on, log in as the service's role (its credentials in the run's
    # secrets, as services.common.secrets reads them)
    cred = os.environ.get("URSA_BUS_CREDENTIALS") or os.path.join(
        os.environ.get("URSA_SECRETS_DIR")
        or os.path.join(os.environ.get("URSA_RUNS_DIR", "runs"), run, "secrets"),
        f"{service}.cred",
    )
    if os.environ.get("URSA_BUS_AUTH", "auto") != "off" and os.path.exists(cred):
        with open(cred) as f:
            user, _, password = f.read().strip().partition(":")
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([router]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", json.dumps(int(TIMEOUT_S * 1000)))
    conf.insert_json5("connect/exit_on_failure", "true")
    with zenoh.open(conf) as session:
        found = [
            str(r.ok.key_expr)
            for r in session.liveliness().get(key, timeout=TIMEOUT_S)
            if r.ok is not None
        ]
    if not found:
        raise RuntimeError(f"no liveliness token {key} at {router}")
    return f"alive: {', '.join(sorted(found))}"


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    mode, rest = argv[0], argv[1:]
    try:
        if mode == "tcp":
            msg = check_tcp(rest[0] if rest else None)
        elif mode == "http":
            msg = check_http(rest[0])
        elif mode == "alive":
            msg = check_alive(rest[0], rest[1] if len(rest) > 1 else None)
        else:
            print(f"unknown check {mode!r}", file=sys.stderr)
            return 2
    except (OSError, urllib.error.URLError, RuntimeError, IndexError) as e:
        print(f"unhealthy: {mode} {' '.join(rest)}: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # zenoh.ZError and friends: unhealthy, never a traceback
        print(f"unhealthy: {mode} {' '.join(rest)}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    print(msg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
