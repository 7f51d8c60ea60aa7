"""``ursa eval curves``: training curves over environment steps from a run's metrics.

Reads ``<run>/metrics/*.jsonl`` (one stats row per line, as every service appends them). The
x-axis is the total number of environment steps over all collectors: each collector's ``steps``
counter is interpolated in time and summed, and every other series (repertoire, learner) is
placed on it by its time stamp. A counter that goes down (a collector restarted from zero) is
made cumulative again. Curves:

- safety-violation rate: Δunsafe steps / Δsteps over a trailing window of ``window`` env steps
  when the collectors report ``unsafe_total``, else the mean of their own sliding-window
  ``violation_rate``;
- rescues per hour of robot time: Δrescues / Δ(steps / control rate) over the same window
  (hour = 3600 s);
- return: mean over collectors of ``return_mean`` (return per skill period);
- repertoire size, δ and entropy bound (the repertoire's stats).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ursa.eval.common import pyplot, save_figure, write_csv, write_json
from ursa.eval.loading import iter_metrics

PANELS = (
    ("violation_rate", "safety-violation rate"),
    ("rescues_per_hour", "rescues per hour"),
    ("return", "return per skill period"),
    ("repertoire_size", "repertoire size"),
    ("delta", "δ"),
    ("entropy_bound", "entropy lower bound"),
)
MAX_POINTS = 400


@dataclass
class Series:
    t: list[float] = field(default_factory=list)
    v: list[float] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        t, v = np.asarray(self.t, np.float64), np.asarray(self.v, np.float64)
        order = np.argsort(t, kind="stable")
        return t[order], v[order]


def cumulative(v: np.ndarray) -> np.ndarray:
    """A counter made non-decreasing: after a drop (a restart from zero), the value reached
    before the drop is added to everything that follows."""
    v = np.asarray(v, np.float64)
    if len(v) == 0:
        return v
    out = v.copy()
    offset = 0.0
    for i in range(1, len(v)):
        if v[i] < v[i - 1]:
            offset += v[i - 1]
        out[i] = v[i] + offset
    return out


def windowed_rate(num: np.ndarray, den: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """(indices, rates): for each point i > 0, Δnum / Δden from the latest earlier point j with
    den[i] − den[j] ≥ ``window`` (the previous point when none is that far back). ``den`` must
    be non-decreasing; points where Δden is 0 are skipped."""
    idx, rates = [], []
    for i in range(1, len(den)):
        j = int(np.searchsorted(den, den[i] - window, side="right")) - 1
        j = min(max(j, 0), i - 1)
        d = den[i] - den[j]
        if d > 0:
            idx.append(i)
            rates.append((num[i] - num[j]) / d)
    return np.asarray(idx, np.int64), np.asarray(rates, np.float64)


def load_series(run_dir: Path) -> dict[str, dict[str, dict[str, Series]]]:
    """service -> id -> scalar name -> series."""
    out: dict[str, dict[str, dict[str, Series]]] = defaultdict(lambda: defaultdict(dict))
    for row in iter_metrics(run_dir):
        t = float(row.get("t", 0.0))
        svc, sid = str(row["service"]), str(row["id"])
        for k, v in row["scalars"].items():
            try:
                fv = float(v)
            except (TypeError, ValueError):
                continue
            s = out[svc][sid].setdefault(k, Series())
            s.t.append(t)
            s.v.append(fv)
    return out


def compute_curves(
    run_dir: Path, control_hz: float = 20.0, window: float | None = None
) -> dict[str, dict[str, np.ndarray]]:
    """Curve name -> {"steps", "t", "value"} arrays (see the module docstring). ``window``:
    env steps over which rates are taken (default: 1/25 of the run, at least 1)."""
    series = load_series(run_dir)
    collectors = series.get("collector", {})
    steps_by_c = {cid: s["steps"].arrays() for cid, s in collectors.items() if "steps" in s}
    if not steps_by_c:
        raise ValueError(f"no collector metrics with 'steps' under {run_dir}/metrics")
    times = np.unique(np.concatenate([t for t, _ in steps_by_c.values()]))
    if len(times) > MAX_POINTS:
        times = times[np.linspace(0, len(times) - 1, MAX_POINTS).round().astype(int)]

    def total(name: str, at: np.ndarray) -> np.ndarray | None:
        acc = np.zeros(len(at))
        found = False
        for s in collectors.values():
            if name in s:
                t, v = s[name].arrays()
                acc += np.interp(at, t, cumulative(v), left=0.0)
                found = True
        return acc if found else None

    steps = total("steps", times)
    assert steps is not None

    def on_steps(t: np.ndarray) -> np.ndarray:
        return np.asarray(np.interp(t, times, steps))

    curves: dict[str, dict[str, np.ndarray]] = {}

    def put(name: str, t: np.ndarray, v: np.ndarray) -> None:
        curves[name] = {"steps": on_steps(t), "t": t, "value": np.asarray(v, np.float64)}

    win = max(float(steps[-1]) / 25.0, 1.0) if window is None else float(window)
    unsafe = total("unsafe_total", times)
    idx, rate = (
        windowed_rate(unsafe, steps, win)
        if unsafe is not None
        else (np.zeros(0, np.int64), np.zeros(0))
    )
    if len(idx):
        put("violation_rate", times[idx], rate)
    else:
        vals = [s["violation_rate"].arrays() for s in collectors.values() if "violation_rate" in s]
        if vals:
            put("violation_rate", times, np.mean([np.interp(times, t, v) for t, v in vals], 0))
    rescues = total("rescues", times)
    if rescues is not None:
        idx, rate = windowed_rate(rescues, steps, win)
        if len(idx):  # per step -> per hour of robot time
            put("rescues_per_hour", times[idx], rate * control_hz * 3600.0)
    rets = [s["return_mean"].arrays() for s in collectors.values() if "return_mean" in s]
    if rets:
        put("return", times, np.mean([np.interp(times, t, v) for t, v in rets], 0))
    reps = series.get("repertoire", {})
    for key, name in (
        ("size", "repertoire_size"),
        ("delta", "delta"),
        ("entropy_bound", "entropy_bound"),
    ):
        for s in reps.values():  # one repertoire service per run
            if key in s:
                t, v = s[key].arrays()
                put(name, t, v)
                break
    for s in series.get("learner", {}).values():
        if "updates" in s:
            t, v = s["updates"].arrays()
            put("learner_updates", t, v)
            break
    return curves


def write_curves(
    run_dir: Path, out: Path, control_hz: float = 20.0, window: float | None = None
) -> dict[str, Any]:
    """curves.json, curves.csv and curves.png; returns the JSON summary."""
    curves = compute_curves(run_dir, control_hz, window)
    summary: dict[str, Any] = {
        "run": run_dir.name,
        "control_hz": control_hz,
        "window": window,
        "env_steps": float(max(c["steps"].max() for c in curves.values() if len(c["steps"]))),
        "final": {k: float(c["value"][-1]) for k, c in curves.items() if len(c["value"])},
        "mean": {k: float(np.mean(c["value"])) for k, c in curves.items() if len(c["value"])},
        "points": {k: len(c["value"]) for k, c in curves.items()},
    }
    write_json(out / "curves.json", summary)
    rows = []
    for name, c in curves.items():
        for s, t, v in zip(c["steps"], c["t"], c["value"], strict=True):
            rows.append([name, s, t, v])
    write_csv(out / "curves.csv", ["curve", "env_steps", "t", "value"], rows)

    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for ax, (name, title) in zip(axes.flat, PANELS, strict=True):
        panel = curves.get(name)
        if panel is None or not len(panel["value"]):
            ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)
        else:
            ax.plot(panel["steps"], panel["value"], lw=1.2)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    fig.suptitle(f"Training curves of {run_dir.name}", fontsize=11)
    fig.tight_layout()
    save_figure(fig, out / "curves.png")
    return summary
