"""The pure core imports no service library (zenoh, FastAPI, uvicorn, viser)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {"zenoh", "fastapi", "uvicorn", "viser", "starlette", "services"}


def test_core_sources_import_no_service_library() -> None:
    offenders = []
    for path in (ROOT / "ursa").rglob("*.py"):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            offenders += [
                f"{path.relative_to(ROOT)}: {n}" for n in names if n.split(".")[0] in FORBIDDEN
            ]
    assert not offenders, offenders


def test_importing_the_core_loads_no_service_library() -> None:
    code = (
        "import sys, importlib, pkgutil, ursa\n"
        "for m in pkgutil.walk_packages(ursa.__path__, 'ursa.'):\n"
        "    importlib.import_module(m.name)\n"
        f"bad = sorted(n for n in sys.modules if n.split('.')[0] in {sorted(FORBIDDEN)!r})\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", out.stdout


def _imports(path: Path) -> list[str]:
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def test_no_service_imports_another_services_modules() -> None:
    """A service package (services/<name>/) imports only itself, services.common, proto and the
    core: what two services share lives in services/common/."""
    offenders = []
    for pkg in sorted(p for p in (ROOT / "services").iterdir() if (p / "__init__.py").exists()):
        if pkg.name == "common":
            continue
        for path in pkg.rglob("*.py"):
            for n in _imports(path):
                parts = n.split(".")
                if (
                    parts[0] == "services"
                    and len(parts) > 1
                    and parts[1] not in (pkg.name, "common")
                ):
                    offenders.append(f"{path.relative_to(ROOT)}: {n}")
    assert not offenders, offenders


def test_services_common_imports_no_service() -> None:
    offenders = [
        f"{path.relative_to(ROOT)}: {n}"
        for path in (ROOT / "services" / "common").rglob("*.py")
        for n in _imports(path)
        if n.startswith("services.") and not n.startswith("services.common")
    ]
    assert not offenders, offenders
