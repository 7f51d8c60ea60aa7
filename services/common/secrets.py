"""A run's secrets: the bus MAC key, per-role router credentials, and the router's access rules.

``ursa secrets`` (or the router, when authentication is on and none exist yet) writes them to
``<run dir>/secrets/`` (or ``--bus.secrets DIR``), each file mode 0600:

| file | what |
|---|---|
| ``bus.key`` | 32 random bytes, hex: the HMAC-SHA256 key of every bus frame (``proto.codec``) |
| ``users`` | the router's user/password dictionary (``user:password`` per line) |
| ``<role>.cred`` | ``user:password`` of one role (``learner``, ``collector``, ...) |
| ``bridge.cred`` | ``user:password`` a second router logs in to the main one with |
| ``router.zid`` | the main router's Zenoh id (hex), which a second router recognises it by |

Authentication (``--bus.auth``): ``on``, ``off`` or ``auto`` (default): on when an endpoint the
process uses is not loopback, or when the secrets directory already holds the role's
credentials (router: the dictionary). Off by default on loopback, then; on in compose.

Access rules (Zenoh ACL, default deny): every authenticated role may subscribe, query and
declare liveliness subscribers under ``ursa/{run}/**``; a role may publish, reply, declare
queryables and liveliness tokens only under its own ``ursa/{run}/{role}/**`` (and
``ursa/{run}/alive/{role}/**``). So only the learner publishes weights, only collectors
transitions and features, only the repertoire snapshots.

Two routers bridged (collectors on another machine behind their own router, which connects to
the main one: ``python -m services.router --connect tcp/<main>:7447``): the second router logs
in to the main one as ``bridge``, which may publish only what collectors publish; the second
router enforces the same per-role rules on its own clients and admits what comes from the main
router (recognised by ``router.zid``; the main router already checked it) under every rule.
"""

from __future__ import annotations

import logging
import os
import secrets as _random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from proto.topics import SERVICES, Topics
from services.common.config import BusConfig, RunConfig
from ursa.rundir import RunDir

log = logging.getLogger(__name__)

ROLES: tuple[str, ...] = SERVICES
"""Roles with their own credentials: one per service kind (collectors share one)."""
KEY_FILE = "bus.key"
USERS_FILE = "users"
BRIDGE = "bridge"
"""The user a second router logs in to the main one as (collectors' rights)."""
ROUTER_ZID_FILE = "router.zid"
AUTH_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str


@dataclass(frozen=True)
class RouterAuth:
    dictionary: Path
    """The user/password dictionary file."""
    run_id: str
    """The run whose keys the access rules cover."""


def secrets_dir(bus: BusConfig, run: RunConfig | None) -> Path | None:
    """``bus.secrets`` if set, else ``<run dir>/secrets``; None when neither is known."""
    if bus.secrets:
        return Path(bus.secrets)
    return None if run is None else RunDir(run.dir).secrets


def is_loopback(endpoint: str) -> bool:
    """Whether a Zenoh endpoint (``tcp/HOST:PORT``) or a bare host is a loopback address."""
    host = endpoint.split("/", 1)[-1]
    host = host.rsplit(":", 1)[0] if host.count(":") == 1 or host.startswith("[") else host
    host = host.strip("[]").split("#", 1)[0]
    return host == "localhost" or host.startswith("127.") or host == "::1"


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def generate(directory: Path) -> Path:
    """Write a run key and one user/password per role into ``directory`` (kept if present);
    returns the directory."""
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    if not (directory / KEY_FILE).exists():
        _write_private(directory / KEY_FILE, _random.token_hex(32) + "\n")
    if not (directory / USERS_FILE).exists():
        creds = {role: _random.token_urlsafe(24) for role in ROLES}
        for role, pw in creds.items():
            path = directory / f"{role}.cred"
            if path.exists():
                path.unlink()
            _write_private(path, f"{role}:{pw}\n")
        _write_private(
            directory / USERS_FILE, "".join(f"{role}:{pw}\n" for role, pw in creds.items())
        )
    if not (directory / f"{BRIDGE}.cred").exists():  # also added to secrets made before it
        pw = _random.token_urlsafe(24)
        with open(directory / USERS_FILE, "a") as f:
            f.write(f"{BRIDGE}:{pw}\n")
        _write_private(directory / f"{BRIDGE}.cred", f"{BRIDGE}:{pw}\n")
    if not (directory / ROUTER_ZID_FILE).exists():
        # a Zenoh id: at most 16 bytes, hex, not zero
        _write_private(directory / ROUTER_ZID_FILE, "1" + _random.token_hex(15) + "\n")
    return directory


def read_router_zid(directory: Path) -> str:
    """The main router's Zenoh id (``router.zid``); ValueError when missing or malformed."""
    path = directory / ROUTER_ZID_FILE
    try:
        zid = path.read_text().strip()
        int(zid, 16)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path} does not hold a router id: {e}") from e
    return zid


def read_key(path: Path) -> bytes:
    """A run key file (hex) -> its bytes; ValueError when it is not a usable key."""
    try:
        key = bytes.fromhex(path.read_text().strip())
    except ValueError as e:
        raise ValueError(f"{path} is not a hex run key") from e
    if len(key) < 16:
        raise ValueError(f"{path} holds a {len(key)}-byte key; at least 16 needed")
    return key


def read_credentials(path: Path) -> Credentials:
    """A ``user:password`` file -> Credentials; ValueError when malformed."""
    user, sep, password = path.read_text().strip().partition(":")
    if not sep or not user or not password:
        raise ValueError(f"{path} does not hold 'user:password'")
    return Credentials(user, password)


def find_run_key(bus: BusConfig, run: RunConfig | None) -> bytes | None:
    """The run key of ``bus.key_file``, else of the secrets directory when present."""
    if bus.key_file:
        return read_key(Path(bus.key_file))
    d = secrets_dir(bus, run)
    if d is not None and (d / KEY_FILE).exists():
        return read_key(d / KEY_FILE)
    return None


def _mode(bus: BusConfig) -> str:
    if bus.auth not in AUTH_MODES:
        raise ValueError(f"bus.auth is {bus.auth!r}; choose one of {', '.join(AUTH_MODES)}")
    return bus.auth


def client_credentials(
    bus: BusConfig, role: str | None, run: RunConfig | None
) -> Credentials | None:
    """The credentials a client of ``role`` logs in with, None when authentication is off;
    raises ``SystemExit`` with what to do when it is on and they are missing."""
    mode = _mode(bus)
    if mode == "off":
        return None
    if bus.credentials:
        return read_credentials(Path(bus.credentials))
    d = secrets_dir(bus, run)
    path = None if d is None or role is None else d / f"{role}.cred"
    if path is not None and path.exists():
        return read_credentials(path)
    if mode == "on" or not is_loopback(bus.router):
        where = path or "a credentials file"
        raise SystemExit(
            f"authentication is on (router {bus.router}, bus.auth={mode}) but "
            f"{where} is missing: run `ursa secrets` for this run, or pass "
            "--bus.credentials FILE (--bus.auth off on a trusted loopback)"
        )
    return None


def router_auth(bus: BusConfig, run: RunConfig | None) -> RouterAuth | None:
    """The router's authentication, None when off; generates the secrets when it is on and
    there are none yet."""
    mode = _mode(bus)
    if mode == "off":
        return None
    d = secrets_dir(bus, run)
    has = d is not None and (d / USERS_FILE).exists()
    if not has and mode == "auto" and is_loopback(bus.listen):
        return None
    if d is None:
        raise SystemExit("authentication is on: give the router --bus.secrets DIR or a run")
    if not has:
        generate(d)
        log.info("generated the run's secrets in %s", d)
    return RouterAuth(d / USERS_FILE, run.run_id if run is not None else "*")


def access_control(run_id: str, upstream_zid: str | None = None) -> dict[str, Any]:
    """The router's ACL (Zenoh 1.x ``access_control``) for one run; see the module docstring.
    ``upstream_zid``: this is a second router, connected to the main router of that id."""
    root = Topics(run_id).root if run_id != "*" else "ursa/*"
    everyone_reads = {
        "id": "read",
        "permission": "allow",
        "flows": ["ingress", "egress"],
        "messages": [
            "declare_subscriber",
            "query",
            "declare_liveliness_subscriber",
            "liveliness_query",
        ],
        "key_exprs": [f"{root}/**"],
    }
    delivered = {
        "id": "delivered",
        "permission": "allow",
        "flows": ["egress"],
        "messages": ["put", "delete", "reply", "liveliness_token"],
        "key_exprs": [f"{root}/**"],
    }
    rules: list[dict[str, Any]] = [everyone_reads, delivered]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = [
        {"rules": ["read", "delivered"], "subjects": [f"role-{r}" for r in ROLES]}
    ]
    for role in ROLES:
        rules.append(
            {
                "id": f"own-{role}",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["put", "delete", "reply", "declare_queryable", "liveliness_token"],
                "key_exprs": [f"{root}/{role}/**", f"{root}/alive/{role}/**"],
            }
        )
        subjects.append({"id": f"role-{role}", "usernames": [role]})
        policies.append({"rules": [f"own-{role}"], "subjects": [f"role-{role}"]})
    # a second router's login: it relays its collectors
    subjects.append({"id": "role-bridge", "usernames": [BRIDGE]})
    policies.append({"rules": ["read", "delivered", "own-collector"], "subjects": ["role-bridge"]})
    if upstream_zid is not None:
        subjects.append({"id": "upstream", "zids": [upstream_zid]})
        policies.append(
            {
                "rules": ["read", "delivered", *(f"own-{r}" for r in ROLES)],
                "subjects": ["upstream"],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


@dataclass(frozen=True)
class SecretsArgs:
    """Write a run's bus key and router credentials (kept if present) in <run>/secrets."""

    bus: BusConfig = field(default_factory=BusConfig)
    run: RunConfig = field(default_factory=RunConfig)


def secrets_command(args: SecretsArgs) -> int:
    """``ursa secrets``: write a run's secrets (kept if present) and print where."""
    d = secrets_dir(args.bus, args.run)
    assert d is not None
    print(generate(d))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``ursa secrets`` on its own; returns the exit status."""
    import tyro

    return secrets_command(tyro.cli(SecretsArgs, args=argv, prog="ursa secrets"))
