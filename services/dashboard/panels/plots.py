"""Live time plots (uPlot) of every scalar every service publishes, grouped generically.

Collector scalars: one plot per key with one line per collector (violation rate, rescues, return,
steps/s, policy version, ...). Other services: keys ``group/name`` share the plot ``group`` (all
``loss/*`` together); a few related plain keys are grouped by name (λ1/λ2 means); any other key
gets its own plot. Plots appear when their first value arrives, in a folder per service; each
update sends at most ``max_points`` points per line (:func:`history.align`).
"""

from __future__ import annotations

import contextlib
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import numpy as np
import viser
import viser.uplot

from services.common.history import align

SKIP_KEYS = frozenset({"uptime_s", "incarnation"})
"""Scalars not worth a plot."""
NAMED_GROUPS: dict[str, str] = {
    "lambda1_mean": "λ1 / λ2 mean",
    "lambda2_mean": "λ1 / λ2 mean",
    "delta": "δ",
    "entropy_bound": "entropy bound",
    "accepted_per_s": "commits/s",
    "rejected_per_s": "commits/s",
}
PALETTE = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)
SERVICE_ORDER = ("collector", "learner", "repertoire", "evaluator", "dashboard", "api")
PRIORITY = (
    "violation_rate",
    "rescues",
    "return_mean",
    "steps_per_s",
    "loss",
    "λ1 / λ2 mean",
    "delta_mean",
    "entropy_bound",
    "replay_steps",
    "policy_version",
    "policy_lag",
    "size",
    "δ",
    "entropy bound",
    "commits/s",
)
"""Plots shown first, in this order (by title); the others follow alphabetically."""

PlotKey = tuple[str, str]
"""(service, plot title)."""
SeriesKey = tuple[str, str, str]
"""(service, id, scalar key), as in ``LiveState.series``."""


def plot_layout(
    keys: list[SeriesKey], max_plots: int = 80
) -> dict[PlotKey, list[tuple[str, SeriesKey]]]:
    """Group series into plots: (service, title) -> [(line label, series key)], sorted."""
    plots: dict[PlotKey, list[tuple[str, SeriesKey]]] = defaultdict(list)
    ids_of: dict[str, set[str]] = defaultdict(set)
    for svc, sid, _ in keys:
        ids_of[svc].add(sid)
    for key in sorted(keys):
        svc, sid, k = key
        if k in SKIP_KEYS:
            continue
        if svc == "collector":
            plots[(svc, k)].append((sid, key))
            continue
        if "/" in k:
            title, label = k.split("/", 1)
        elif k in NAMED_GROUPS:
            title, label = NAMED_GROUPS[k], k
        else:
            title, label = k, k
        if len(ids_of[svc]) > 1:
            label = f"{sid}:{label}"
        plots[(svc, title)].append((label, key))

    def rank(pk: PlotKey) -> tuple[int, int, str]:
        svc, title = pk
        s = SERVICE_ORDER.index(svc) if svc in SERVICE_ORDER else len(SERVICE_ORDER)
        p = PRIORITY.index(title) if title in PRIORITY else len(PRIORITY)
        return s, p, title

    ordered = sorted(plots.items(), key=lambda kv: rank(kv[0]))
    return dict(ordered[:max_plots])


class PlotsPanel:
    """uPlot handles kept in sync with the series present; call ``update`` at a few Hz."""

    def __init__(
        self,
        server: viser.ViserServer,
        container: Any = None,
        max_points: int = 400,
        max_plots: int = 80,
        max_lines: int = 12,
    ) -> None:
        self.server = server
        self.container = container if container is not None else contextlib.nullcontext()
        self.max_points = max_points
        self.max_plots = max_plots
        self.max_lines = max_lines
        self.empty = server.gui.add_markdown("*no data yet: plots appear when services publish*")
        self.folders: dict[str, viser.GuiFolderHandle] = {}
        self.plots: dict[PlotKey, tuple[tuple[str, ...], viser.GuiUplotHandle]] = {}
        self.points_sent = 0

    def _folder(self, service: str) -> viser.GuiFolderHandle:
        f = self.folders.get(service)
        if f is None:
            order = SERVICE_ORDER.index(service) if service in SERVICE_ORDER else len(SERVICE_ORDER)
            with self.container:  # plots are created later, from the page loop's thread
                f = self.server.gui.add_folder(
                    service,
                    order=100 + order,
                    expand_by_default=service in ("collector", "learner", "repertoire"),
                )
            self.folders[service] = f
        return f

    def update(self, series: Mapping[SeriesKey, tuple[np.ndarray, np.ndarray]]) -> int:
        """Create, refresh or remove plots; returns the number of plots shown."""
        layout = plot_layout([k for k, (t, _) in series.items() if len(t)], self.max_plots)
        rank = {pk: i for i, pk in enumerate(layout)}
        points = 0
        with self.server.atomic():
            for pk in [pk for pk in self.plots if pk not in layout]:
                self.plots.pop(pk)[1].remove()
            for pk, lines in layout.items():
                lines = lines[: self.max_lines]
                labels = tuple(lbl for lbl, _ in lines)
                x, ys = align([series[sk] for _, sk in lines], self.max_points)
                if len(x) == 0:
                    continue
                if len(x) == 1:  # uPlot needs two points to draw a line
                    x = np.array([x[0] - 1.0, x[0]])
                    ys = [np.repeat(y, 2) for y in ys]
                data = (x, *ys)
                points += len(x) * len(ys)
                current = self.plots.get(pk)
                if current is not None and current[0] == labels:
                    current[1].data = data
                    continue
                if current is not None:
                    current[1].remove()
                series_cfg = (
                    viser.uplot.Series(label="time"),
                    *(
                        viser.uplot.Series(label=lbl, stroke=PALETTE[i % len(PALETTE)], width=1.5)
                        for i, lbl in enumerate(labels)
                    ),
                )
                with self._folder(pk[0]):
                    handle = self.server.gui.add_uplot(
                        data=data,
                        series=series_cfg,
                        title=pk[1],
                        aspect=1.6,
                        order=float(rank[pk]),
                        legend=viser.uplot.Legend(show=True),
                    )
                self.plots[pk] = (labels, handle)
            self.empty.visible = not self.plots
        self.points_sent += points
        return len(self.plots)
