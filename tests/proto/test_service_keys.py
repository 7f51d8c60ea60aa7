"""Every key a service declares is built by ``proto/topics.py``, and every key its code builds is
declared.

Each service module's docstring lists the keys it subscribes to, queries, serves, publishes
and declares liveliness on (``Subscribes:``, ``Queries:``, ``Queryables:``, ``Publishes:``,
``Liveliness:``). Its code reaches the bus only through a :class:`proto.topics.Topics`: each
``topics.<member>`` call site in the service's package is evaluated (string-constant arguments
as written, any other argument as an instance id) and the key it builds must be one its
docstring declares; each declared key must be one ``Topics`` builds. The shared
:class:`services.common.runtime.ServiceRuntime` adds every service's liveliness token and stats
key. No module under ``services/`` spells a key by hand.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import itertools
import re
from pathlib import Path

import pytest

from proto.topics import SERVICES, Topics

ROOT = Path(__file__).resolve().parents[2]
RUN = "run-1"
ID = "inst-7"  # stands for any instance id ({cid}, {id}) or a non-constant argument
SECTIONS = ("Subscribes:", "Queries:", "Queryables:", "Queryable:", "Publishes:", "Liveliness:")
KEY = re.compile(r"ursa/\{run\}/[^\s(),;]+")
#: Topics members that build keys (the others parse keys or hold the run's prefix)
BUILDERS = sorted(
    name
    for name, v in vars(Topics).items()
    if not name.startswith("_")
    and name not in ("parse_alive", "last_chunk")
    and (isinstance(v, property) or inspect.isfunction(v))
)


def _normalise(key: str) -> str:
    """``{run}`` -> the run; a placeholder (``{cid}``, ``{id}``, ``{service}``) or ``main`` (the
    default id of a single-instance service) -> the instance id."""
    key = re.sub(r"\{[a-z_]+\}", ID, key.replace("{run}", RUN))
    return re.sub(r"/main$", f"/{ID}", key)


def _declared(service: str) -> set[str]:
    """The keys ``services/<service>/service.py``'s docstring declares (normalised)."""
    doc = importlib.import_module(f"services.{service}.service").__doc__ or ""
    keys: set[str] = set()
    section = False
    for line in doc.splitlines():
        head = line.strip().split(" ", 1)[0]
        if head.endswith(":"):
            section = head in SECTIONS
        elif not line.startswith(" ") or not line.strip():
            section = False
        if section:
            for k in KEY.findall(line):
                keys.add(_normalise(k.rstrip(".")))
    return keys


def _built() -> set[str]:
    """Every key ``Topics`` builds for the run: each builder with every combination of service
    name, wildcard and instance id as arguments."""
    t = Topics(RUN)
    out: set[str] = set()
    for name in BUILDERS:
        member = getattr(Topics, name)
        if isinstance(member, property):
            out.add(getattr(t, name))
            continue
        params = list(inspect.signature(member).parameters)[1:]
        choices = [[*SERVICES, ID, "*"] if p == "service" else [ID, "*"] for p in params]
        for args in itertools.product(*choices):
            out.add(getattr(t, name)(*args))
    return out


def _is_topics(node: ast.expr) -> bool:
    """``t``, ``topics`` or ``<anything>.topics``: a Topics instance by the services' naming."""
    return (isinstance(node, ast.Name) and node.id in ("t", "topics")) or (
        isinstance(node, ast.Attribute) and node.attr == "topics"
    )


def _code_keys(package: Path) -> dict[str, list[str]]:
    """key -> "file:line" of each Topics call site under ``package``, evaluated."""
    t = Topics(RUN)
    out: dict[str, list[str]] = {}
    for path in sorted(package.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        calls = {id(n.func): n for n in ast.walk(tree) if isinstance(n, ast.Call)}
        for node in ast.walk(tree):
            if not (
                isinstance(node, ast.Attribute) and node.attr in BUILDERS and _is_topics(node.value)
            ):
                continue
            if isinstance(getattr(Topics, node.attr), property):
                key = getattr(t, node.attr)
            else:
                call = calls.get(id(node))
                assert call is not None, f"{path}:{node.lineno}: Topics.{node.attr} not called"
                args = [
                    a.value if isinstance(a, ast.Constant) and isinstance(a.value, str) else ID
                    for a in call.args
                ]
                key = getattr(t, node.attr)(*args)
            out.setdefault(key, []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return out


SERVICE_PACKAGES = sorted(
    p.parent.name for p in (ROOT / "services").glob("*/service.py") if p.parent.name in SERVICES
)


def test_every_service_is_checked() -> None:
    assert sorted(SERVICES) == SERVICE_PACKAGES


@pytest.mark.parametrize("service", SERVICE_PACKAGES)
def test_declared_keys_are_built_by_topics(service: str) -> None:
    declared = _declared(service)
    assert declared, f"services/{service}/service.py declares no keys"
    unknown = declared - _built()
    assert not unknown, f"services/{service} declares keys proto/topics.py never builds: {unknown}"


@pytest.mark.parametrize("service", SERVICE_PACKAGES)
def test_every_key_the_code_builds_is_declared(service: str) -> None:
    t = Topics(RUN)
    used = _code_keys(ROOT / "services" / service)
    # what ServiceRuntime declares and publishes for every service (services/common/runtime.py)
    used.setdefault(t.alive(service, ID), []).append("ServiceRuntime liveliness token")
    used.setdefault(t.stats(service, ID), []).append("ServiceRuntime stats")
    missing = {k: where for k, where in used.items() if k not in _declared(service)}
    assert not missing, f"services/{service} uses keys its docstring does not declare: {missing}"


def test_runtime_builds_only_the_liveliness_and_stats_keys() -> None:
    used = _code_keys(ROOT / "services" / "common")
    t = Topics(RUN)
    assert set(used) <= {t.alive(ID, ID), t.stats(ID, ID)}, used


def _docstrings(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                ids.add(id(body[0].value))
    return ids


#: functions allowed to spell key expressions: the router's access rules cover every run
#: (``ursa/*``), which no Topics (one run) builds
BY_HAND_ALLOWED = {("services/common/secrets.py", "access_control")}


def test_no_service_spells_a_key_by_hand() -> None:
    bad = []
    for path in sorted((ROOT / "services").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        docs = _docstrings(tree)
        rel = str(path.relative_to(ROOT))
        allowed = {
            id(n)
            for f in ast.walk(tree)
            if isinstance(f, ast.FunctionDef) and (rel, f.name) in BY_HAND_ALLOWED
            for n in ast.walk(f)
        }
        for node in ast.walk(tree):
            if id(node) in allowed:
                continue
            text = None
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in docs
            ):
                text = node.value
            elif (
                isinstance(node, ast.JoinedStr)
                and node.values
                and isinstance(node.values[0], ast.Constant)
            ):
                text = str(node.values[0].value)
            if text is not None and (
                text.startswith("ursa/") or "/alive/" in text or "/stats/" in text
            ):
                bad.append(f"{rel}:{getattr(node, 'lineno', '?')}: {text!r}")
    assert not bad, bad


def test_the_builders_cover_the_documented_table() -> None:
    """The module docstring's table of keys lists exactly what the builders make."""
    import proto.topics as topics

    rows = [line for line in (topics.__doc__ or "").splitlines() if line.startswith("| ``")]
    table = {_normalise(k) for line in rows for k in re.findall(r"``(ursa/\{run\}/[^`]+)``", line)}
    assert len(table) == len(rows) == 14
    built = _built()
    assert table <= built, table - built
    # every builder makes at least one key of the table (with ids filled in)
    t = Topics(RUN)
    for name in BUILDERS:
        member = getattr(Topics, name)
        if isinstance(member, property):
            keys = {getattr(t, name)}
        else:
            params = list(inspect.signature(member).parameters)[1:]
            keys = {
                getattr(t, name)(*args)
                for args in itertools.product(
                    *[[*SERVICES, ID] if p == "service" else [ID] for p in params]
                )
            }
        assert name == "all_stats" or keys & table, (name, keys)
