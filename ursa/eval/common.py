"""Helpers shared by the evaluations: output files, figures, skill choice."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ursa.eval.loading import LoadedRun
from ursa.eval.rollout import farthest_point_sampling
from ursa.rundir import atomic_write

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def jsonable(obj: Any) -> Any:
    """Numbers and arrays as plain JSON (NaN and inf as null)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: Path, data: Any) -> Path:
    return atomic_write(path, json.dumps(jsonable(data), indent=2) + "\n")


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> Path:
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(header)
    for row in rows:
        w.writerow([_cell(v) for v in row])
    return atomic_write(path, buf.getvalue())


def _cell(v: Any) -> Any:
    if isinstance(v, float | np.floating):
        return f"{float(v):.6g}"
    if isinstance(v, np.generic):
        return v.item()
    return v


def save_figure(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    pyplot().close(fig)
    return path


def distinct_skills(run: LoadedRun, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n`` most distinct skills (k, D) of a run's repertoire and their ids (k,):
    farthest-point sampling in the Mahalanobis metric of δ (Σ of the repertoire); ``n <= 0``
    or ``n >= N``: every skill, in id order."""
    rep = run.require_repertoire()
    skills, ids = rep.skills, rep.ids
    if 0 < n < len(skills):
        idx = farthest_point_sampling(skills, n, rep.cov)
        return skills[idx], ids[idx]
    return skills, ids


def feature_names(cfg_feature: str, dim: int) -> list[str]:
    """Axis labels of a feature's dimensions."""
    names = {
        "velocity": ["forward velocity (m/s)", "yaw rate (rad/s)"],
        "position": ["x", "y"],
        "contacts": ["FR contact", "FL contact", "RR contact", "RL contact"],
    }.get(cfg_feature, [])
    return [names[i] if i < len(names) else f"phi[{i}]" for i in range(dim)]
