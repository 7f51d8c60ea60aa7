"""The adaptation panel: a running (or the latest) damage-adaptation job of an evaluator.

Jobs arrive as ``AdaptJob`` messages (``evaluator/adapt_state/{id}``, published at every
change). The panel shows, for the newest job: its state, damage, map progress, trials against
the budget, the best return so far, the model's predicted best and the stop reason (markdown);
the returns per trial with the best so far and the model's prediction before each trial (a
uPlot chart); and, on the skill cloud of the Skills tab, the tried skills coloured by their
return (bigger points), the chosen skill (green) and the predicted best (gold). Parsing is
pure (:meth:`JobView.from_msg`) so tests can check what is drawn.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot

from proto import codec
from proto import ursa_pb2 as pb
from services.dashboard.panels.repertoire import Frame, RepertoirePanel, colormap

_CHOSEN_COLOR = (42, 157, 143)
_BEST_COLOR = (255, 183, 3)


@dataclass(frozen=True)
class JobView:
    """What the panel draws of one job (arrays by map row or by trial)."""

    job_id: str
    evaluator: str
    state: str
    stop_reason: str
    damage: str
    frozen: tuple[int, ...]
    budget: int
    map_skills: np.ndarray
    """(N, D)"""
    map_ids: np.ndarray
    """(N,)"""
    mapped: int
    map_cached: bool
    tried: np.ndarray
    """Skills tried (n, D), in order."""
    tried_ids: np.ndarray
    returns: np.ndarray
    """(n,)"""
    predicted: np.ndarray
    """The model's mean for each tried skill before its trial (n,)."""
    chosen_id: int
    chosen_return: float
    best_id: int
    best_mean: float
    updated: float
    created: float

    @classmethod
    def from_msg(cls, msg: pb.AdaptJob) -> JobView:
        skills = np.asarray(codec.from_array(msg.map_skills), np.float64)
        ids = np.asarray(codec.from_array(msg.map_ids), np.int64)
        d = skills.shape[1] if skills.ndim == 2 else 0
        tried = [np.asarray(codec.from_array(t.skill), np.float64) for t in msg.trials]
        return cls(
            job_id=msg.job_id,
            evaluator=msg.evaluator_id,
            state=msg.state,
            stop_reason=msg.stop_reason,
            damage=msg.request.damage or "none",
            frozen=tuple(int(j) for j in msg.request.frozen_joints),
            budget=int(msg.request.budget),
            map_skills=skills.reshape(-1, d) if d else np.zeros((0, 0)),
            map_ids=ids,
            mapped=int(msg.mapped),
            map_cached=bool(msg.map_cached),
            tried=np.stack(tried) if tried else np.zeros((0, d)),
            tried_ids=np.asarray([t.skill_id for t in msg.trials], np.int64),
            returns=np.asarray([t.ret for t in msg.trials], np.float64),
            predicted=np.asarray([t.predicted for t in msg.trials], np.float64),
            chosen_id=int(msg.chosen_skill_id),
            chosen_return=float(msg.chosen_return),
            best_id=int(msg.predicted_best_id),
            best_mean=float(msg.predicted_best_mean),
            updated=float(msg.updated),
            created=float(msg.created),
        )

    def skill(self, skill_id: int) -> np.ndarray | None:
        """Coordinates (D,) of a map skill, None if it is not in the map."""
        rows = np.flatnonzero(self.map_ids == skill_id)
        return self.map_skills[int(rows[0])] if len(rows) else None

    @property
    def best_so_far(self) -> np.ndarray:
        return np.maximum.accumulate(self.returns) if len(self.returns) else self.returns


def job_markdown(job: JobView | None) -> str:
    if job is None:
        return "*no adaptation yet* (`POST /adapt` on the API starts one)"
    damage = job.damage + (f" + frozen joints {list(job.frozen)}" if job.frozen else "")
    lines = [
        f"**job** `{job.job_id}` on evaluator `{job.evaluator}`: **{job.state}**",
        f"**damage:** {damage}",
        f"**map:** {job.mapped}/{len(job.map_ids)} skills measured intact"
        + (" (cached)" if job.map_cached else ""),
        f"**trials:** {len(job.returns)}/{job.budget}",
    ]
    if job.chosen_id >= 0:
        lines.append(f"**best so far:** skill {job.chosen_id}, return {job.chosen_return:.3g}")
    if job.best_id >= 0:
        lines.append(f"**predicted best:** skill {job.best_id}, mean {job.best_mean:.3g}")
    if job.stop_reason:
        lines.append(f"**stopped:** {job.stop_reason}")
    return "  \n".join(lines)


class AdaptPanel:
    """Markdown + chart in its own tab, tried skills and predictions on the skill cloud."""

    def __init__(self, server: viser.ViserServer, skills: RepertoirePanel) -> None:
        self.server = server
        self.skills = skills
        self._lock = threading.Lock()
        self._latest: pb.AdaptJob | None = None
        self._drawn: tuple[str, float, float] | None = None
        self.job: JobView | None = None
        self.info = server.gui.add_markdown(job_markdown(None))
        self.chart: viser.GuiUplotHandle | None = None
        self.tried_cloud = server.scene.add_point_cloud(
            "/skills/adapt/tried",
            np.zeros((1, 3), np.float32),
            colors=(0, 0, 0),
            point_size=0.06,
            point_shape="diamond",
            visible=False,
        )
        self.chosen_marker = server.scene.add_icosphere(
            "/skills/adapt/chosen", radius=0.06, color=_CHOSEN_COLOR, visible=False
        )
        self.best_marker = server.scene.add_icosphere(
            "/skills/adapt/predicted_best", radius=0.045, color=_BEST_COLOR, visible=False
        )
        self.best_label = server.scene.add_label(
            "/skills/adapt/predicted_best_label", "predicted best", visible=False
        )
        self.world = np.zeros((0, 3))

    def on_job(self, msg: pb.AdaptJob) -> None:
        """Bus callback: keep the newest job's newest state."""
        with self._lock:
            cur = self._latest
            if (
                cur is None
                or msg.created > cur.created
                or (msg.job_id == cur.job_id and msg.updated >= cur.updated)
            ):
                self._latest = msg

    def _frame(self, job: JobView) -> Frame:
        # the Skills tab's frame once it shows a snapshot of the same dimension, else the map's
        f = self.skills.frame
        snap = self.skills.snap
        if snap is not None and snap.dim == job.map_skills.shape[1]:
            return f
        return Frame.fit(job.map_skills, self.skills.origin, self.skills.half_size)

    def update(self) -> bool:
        """Redraw if the job changed; True when something was redrawn."""
        with self._lock:
            msg = self._latest
        if msg is None:
            return False
        key = (msg.job_id, msg.updated, float(self.skills.frame.scale))
        if key == self._drawn:
            return False
        job = JobView.from_msg(msg)
        if job.map_skills.size == 0:
            return False
        frame = self._frame(job)
        world = frame.world(job.tried) if len(job.tried) else np.zeros((0, 3))
        chosen = job.skill(job.chosen_id) if job.chosen_id >= 0 else None
        best = job.skill(job.best_id) if job.best_id >= 0 else None
        with self.server.atomic():
            self.info.content = job_markdown(job)
            if len(world):
                self.tried_cloud.points = world.astype(np.float32)
                self.tried_cloud.colors = colormap(job.returns)
            self.tried_cloud.visible = bool(len(world))
            self.chosen_marker.visible = chosen is not None
            if chosen is not None:
                self.chosen_marker.position = tuple(frame.world(chosen))
            self.best_marker.visible = self.best_label.visible = best is not None
            if best is not None:
                pos = tuple(frame.world(best))
                self.best_marker.position = self.best_label.position = pos
            self._draw_chart(job)
        self.job, self.world, self._drawn = job, world, key
        return True

    def _draw_chart(self, job: JobView) -> None:
        n = len(job.returns)
        if n == 0:
            return
        x = np.arange(1, n + 1, dtype=np.float64)
        ys = [job.returns, job.best_so_far, job.predicted]
        if n == 1:  # uPlot needs two points to draw a line
            x = np.array([0.5, 1.0])
            ys = [np.repeat(y, 2) for y in ys]
        data = (x, *ys)
        if self.chart is None:
            self.chart = self.server.gui.add_uplot(
                data=data,
                series=(
                    viser.uplot.Series(label="trial"),
                    viser.uplot.Series(label="return", stroke="#e63946", width=1.5),
                    viser.uplot.Series(label="best so far", stroke="#2a9d8f", width=2.0),
                    viser.uplot.Series(label="predicted", stroke="#999999", width=1.0),
                ),
                title="adaptation: return per trial",
                aspect=1.6,
                legend=viser.uplot.Legend(show=True),
            )
        else:
            self.chart.data = data
