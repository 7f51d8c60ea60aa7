"""The repertoire as a 3-D point cloud in skill space, the collectors' skills, and skill picking.

Skills (N, D) are shown in world coordinates ``origin + (p − centre) · scale`` where p is the skill
padded with zeros (D < 3) or cut to its first three coordinates (D > 3; the colour can still show
any coordinate), fitted into a cube of side ``2 · half_size``. viser 1.1.1's point clouds take no
click callbacks (``PointCloudHandle`` says so), so a click anywhere in the scene
(``scene.on_click``) casts the click's ray against the displayed points and selects the skill
nearest to the ray; a skill id input and a "nearest to z" input do the same from the keyboard.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import viser

from services.common.live import CollectorInfo, SnapshotView

_SKILL_COLOR = (230, 57, 70)
_SELECTED_COLOR = (255, 183, 3)


def _viridis_lut() -> np.ndarray:
    try:
        from matplotlib import colormaps

        return np.asarray(colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3] * 255, np.uint8)
    except Exception:  # matplotlib missing or broken: a plain blue-to-yellow ramp
        t = np.linspace(0.0, 1.0, 256)[:, None]
        return np.asarray((1 - t) * [68, 1, 84] + t * [253, 231, 37], np.uint8)


VIRIDIS = _viridis_lut()


def colormap(values: np.ndarray) -> np.ndarray:
    """Values (N,) -> viridis colours (N, 3) uint8, scaled between the 1st and 99th percentile."""
    v = np.asarray(values, np.float64)
    if len(v) == 0:
        return np.zeros((0, 3), np.uint8)
    v = np.where(np.isfinite(v), v, np.nan)
    if np.all(np.isnan(v)):
        return np.tile(VIRIDIS[0], (len(v), 1))
    lo, hi = np.nanpercentile(v, [1.0, 99.0])
    u = np.zeros_like(v) if hi <= lo else (v - lo) / (hi - lo)
    u = np.nan_to_num(np.clip(u, 0.0, 1.0), nan=0.0)
    return VIRIDIS[(u * 255).astype(np.int64)]


def color_options(dim: int) -> tuple[str, ...]:
    """Choices of the colour dropdown for skills of dimension ``dim``."""
    return ("age", "nn distance", *(f"z[{i}]" for i in range(dim)))


def color_values(snap: SnapshotView, mode: str) -> np.ndarray:
    """The per-skill value (N,) that colours the cloud in ``mode`` (newer skills: higher age)."""
    if mode == "nn distance":
        return snap.nn_dist
    if mode.startswith("z[") and mode.endswith("]"):
        i = int(mode[2:-1])
        if 0 <= i < snap.dim:
            return snap.skills[:, i]
    return snap.ages.astype(np.float64)


def to3(z: np.ndarray) -> np.ndarray:
    """(N, D) or (D,) -> (N, 3) or (3,): zero-padded or cut to the first three coordinates."""
    z = np.asarray(z, np.float64)
    d = z.shape[-1]
    if d >= 3:
        return z[..., :3]
    pad = [(0, 0)] * (z.ndim - 1) + [(0, 3 - d)]
    return np.pad(z, pad)


@dataclass(frozen=True)
class Frame:
    """Skill space -> world: ``world = origin + (to3(z) − centre) · scale``."""

    centre: np.ndarray
    scale: float
    origin: np.ndarray

    @classmethod
    def fit(cls, skills: np.ndarray, origin: Sequence[float], half_size: float) -> Frame:
        p = to3(skills) if len(skills) else np.zeros((1, 3))
        lo, hi = p.min(axis=0), p.max(axis=0)
        half = float(np.max(hi - lo)) / 2.0
        scale = half_size / half if half > 1e-12 else 1.0
        return cls((lo + hi) / 2.0, scale, np.asarray(origin, np.float64))

    def world(self, z: np.ndarray) -> np.ndarray:
        return np.asarray(self.origin + (to3(z) - self.centre) * self.scale)


def pick_on_ray(
    points: np.ndarray, origin: np.ndarray, direction: np.ndarray, tolerance: float
) -> int | None:
    """Index of the point (N, 3) nearest the ray ``origin + t·direction`` (t > 0), or None if no
    point lies within ``tolerance`` of it; among points about equally near the ray, the one
    closest to the camera wins."""
    if len(points) == 0:
        return None
    d = np.asarray(direction, np.float64)
    norm = float(np.linalg.norm(d))
    if not norm > 0:
        return None
    d = d / norm
    v = np.asarray(points, np.float64) - np.asarray(origin, np.float64)
    t = v @ d
    perp = np.linalg.norm(v - t[:, None] * d, axis=1)
    perp = np.where(t > 0, perp, np.inf)
    best = float(perp.min())
    if not best <= tolerance:
        return None
    close = np.flatnonzero(perp <= best + 0.25 * tolerance)
    return int(close[np.argmin(t[close])])


def parse_floats(text: str) -> np.ndarray:
    """ "0.1, -2, 3e-1" -> array; raises ValueError on anything else or a non-finite value."""
    parts = [p for p in text.replace(";", ",").replace(" ", ",").split(",") if p]
    if not parts:
        raise ValueError("no numbers given")
    z = np.array([float(p) for p in parts])
    if not np.all(np.isfinite(z)):
        raise ValueError("coordinates must be finite")
    return z


class RepertoirePanel:
    """Point cloud, collector markers, colour/size controls and the skill selection."""

    def __init__(
        self,
        server: viser.ViserServer,
        origin: Sequence[float] = (0.0, 2.5, 1.2),
        half_size: float = 1.0,
        max_points: int = 20000,
    ) -> None:
        self.server = server
        self.origin = tuple(float(x) for x in origin)
        self.half_size = half_size
        self.max_points = max_points
        self._lock = threading.Lock()
        self.snap: SnapshotView | None = None
        self.frame = Frame(np.zeros(3), 1.0, np.asarray(self.origin))
        self.shown_rows = np.zeros(0, np.int64)
        self.world = np.zeros((0, 3))
        self.selected_id: int | None = None
        self.selection_note = ""
        self._collectors: list[CollectorInfo] = []
        self._rendered: tuple[int, float, str, float] | None = None
        self._markers: dict[str, tuple[viser.IcosphereHandle, viser.LabelHandle]] = {}
        self._dirty = True

        gui = server.gui
        self.color_by = gui.add_dropdown(
            "colour by",
            color_options(3),
            initial_value="age",
            hint="Colour skills by their age or a coordinate",
        )
        self.point_size = gui.add_slider(
            "point size", min=0.005, max=0.1, step=0.005, initial_value=0.03
        )
        self.skill_id = gui.add_number(
            "skill id", 0, min=0, step=1, hint="Select a skill by id (or click near it)"
        )
        self.select_button = gui.add_button("select skill")
        self.z_text = gui.add_text("nearest to z", "", hint="Comma-separated coordinates")
        self.nearest_button = gui.add_button("select nearest")
        self.info = gui.add_markdown("*no skill selected: click near a point*")

        self.cloud = server.scene.add_point_cloud(
            "/skills/cloud",
            np.zeros((1, 3), np.float32) + np.asarray(self.origin, np.float32),
            colors=(120, 120, 120),
            point_size=self.point_size.value,
            point_shape="circle",
            visible=False,
        )
        self.selected_marker = server.scene.add_icosphere(
            "/skills/selected", radius=0.05, color=_SELECTED_COLOR, visible=False
        )
        self.box = server.scene.add_box(
            "/skills/box",
            color=(180, 180, 180),
            dimensions=(2 * half_size,) * 3,
            wireframe=True,
            position=np.asarray(self.origin),
            opacity=0.3,
        )
        self.title = server.scene.add_label(
            "/skills/title",
            "skill space (no data yet)",
            position=np.asarray(self.origin) + np.array([-half_size, -half_size, half_size + 0.15]),
        )

        self.color_by.on_update(lambda _: self._mark_dirty())
        self.point_size.on_update(lambda _: self._mark_dirty())
        self.select_button.on_click(lambda _: self.select_id(int(self.skill_id.value)))
        self.nearest_button.on_click(lambda _: self._select_from_text())

        @server.scene.on_click()
        def _(event: viser.SceneClickEvent) -> None:
            self.on_ray(np.asarray(event.ray_origin), np.asarray(event.ray_direction))

    # ---- selection -------------------------------------------------------------------------
    def _mark_dirty(self) -> None:
        self._dirty = True

    def on_ray(self, origin: np.ndarray, direction: np.ndarray) -> int | None:
        """Select the displayed skill nearest a click's ray; returns its id (None: no hit)."""
        with self._lock:
            world, rows, snap = self.world, self.shown_rows, self.snap
        tol = max(3.0 * float(self.point_size.value), 0.04 * self.half_size)
        i = pick_on_ray(world, origin, direction, tol)
        if i is None or snap is None:
            return None
        sid = int(snap.ids[rows[i]])
        self.select_id(sid)
        return sid

    def select_id(self, skill_id: int) -> None:
        with self._lock:
            self.selected_id = int(skill_id)
            self.selection_note = ""
        self._dirty = True
        self.refresh_selection()

    def _select_from_text(self) -> None:
        try:
            self.select_nearest(parse_floats(self.z_text.value))
        except ValueError as e:
            self.info.content = f"**cannot read z:** {e}"

    def select_nearest(self, z: np.ndarray) -> int | None:
        """Select the skill nearest z (Mahalanobis, the repertoire's metric); returns its id."""
        snap = self.snap
        if snap is None or snap.size == 0:
            self.info.content = "*no repertoire yet*"
            return None
        if len(z) != snap.dim:
            self.info.content = f"**z needs {snap.dim} coordinates, got {len(z)}**"
            return None
        rows, _ = snap.nearest(z, 1)
        sid = int(snap.ids[rows[0]])
        self.select_id(sid)
        return sid

    def selection_markdown(self) -> str:
        snap, sid = self.snap, self.selected_id
        if sid is None:
            return "*no skill selected: click near a point*"
        if snap is None:
            return f"skill {sid}: *no repertoire yet*"
        row = snap.index_of(sid)
        if row is None:
            return f"**skill {sid}** is not in the repertoire (version {snap.version})"
        z = snap.skills[row]
        coords = ", ".join(f"{x:.3f}" for x in z)
        lines = [
            f"**skill {sid}**  z = ({coords})",
            f"age {int(snap.ages[row])} · NN distance {float(snap.nn_dist[row]):.3f} · "
            f"δ = {snap.delta:.3f}",
        ]
        near = []
        for c in self._collectors:
            cz = c.skill
            if cz is None or len(cz) != snap.dim:
                continue
            near.append((snap.distance(cz, z), c.id))
        near.sort()
        if near:
            items = [f"{cid} ({d:.2f}{' ≤ δ' if d <= snap.delta else ''})" for d, cid in near[:8]]
            lines.append("collectors by distance: " + ", ".join(items))
        else:
            lines.append("no collector is executing a skill yet")
        return "  \n".join(lines)

    def refresh_selection(self) -> None:
        snap, sid = self.snap, self.selected_id
        row = None if snap is None or sid is None else snap.index_of(sid)
        content = self.selection_markdown()
        with self.server.atomic():
            if row is not None and snap is not None:
                pos = self.frame.world(snap.skills[row])
                if not np.allclose(self.selected_marker.position, pos):
                    self.selected_marker.position = tuple(pos)
                if not self.selected_marker.visible:
                    self.selected_marker.visible = True
            elif self.selected_marker.visible:
                self.selected_marker.visible = False
            if self.info.content != content:
                self.info.content = content

    # ---- updates ---------------------------------------------------------------------------
    def update(self, snap: SnapshotView | None, collectors: list[CollectorInfo]) -> None:
        """Redraw what changed: the cloud on a new snapshot or setting, markers every call."""
        self._collectors = collectors
        mode = str(self.color_by.value)
        size = float(self.point_size.value)
        key = None if snap is None else (snap.version, snap.stamp, mode, size)
        if snap is not None and (key != self._rendered or self._dirty):
            self._draw_cloud(snap, mode, size)
            self._rendered = key
        self._dirty = False
        self._draw_markers(collectors)
        self.refresh_selection()

    def _draw_cloud(self, snap: SnapshotView, mode: str, size: float) -> None:
        opts = color_options(snap.dim)
        if mode not in opts:
            mode = "age"
        rows = np.arange(snap.size)
        if snap.size > self.max_points:  # keep the newest: they are the ones that change
            rows = np.argsort(snap.ages)[-self.max_points :]
        frame = Frame.fit(snap.skills[rows], self.origin, self.half_size)
        world = frame.world(snap.skills[rows])
        colors = colormap(color_values(snap, mode)[rows])
        with self._lock:
            self.snap, self.frame, self.shown_rows, self.world = snap, frame, rows, world
        title = (
            f"skill space: {len(rows)} skills, D={snap.dim}, coloured by {mode}"
            if len(rows)
            else "skill space (repertoire empty)"
        )
        with self.server.atomic():
            if tuple(self.color_by.options) != opts:
                self.color_by.options = opts
                self.color_by.value = mode  # type: ignore[misc]
            if len(rows):
                self.cloud.points = world.astype(np.float32)
                self.cloud.colors = colors
            self.cloud.point_size = size
            self.cloud.visible = bool(len(rows))
            self.title.text = title

    def _draw_markers(self, collectors: list[CollectorInfo]) -> None:
        """One sphere + label per live collector at its current skill."""
        live = {c.id: c.skill for c in collectors if c.alive and c.skill is not None}
        snap = self.snap
        if snap is None:
            live = {}
        with self.server.atomic():
            for cid in list(self._markers):
                if cid not in live:
                    for h in self._markers.pop(cid):
                        h.remove()
            for cid, z in live.items():
                if snap is not None and len(z) != snap.dim:
                    continue
                pos = tuple(self.frame.world(z))
                if cid not in self._markers:
                    name = "".join(ch if ch.isalnum() else "_" for ch in cid)
                    sphere = self.server.scene.add_icosphere(
                        f"/skills/collectors/{name}", radius=0.035, color=_SKILL_COLOR, position=pos
                    )
                    label = self.server.scene.add_label(
                        f"/skills/collectors/{name}_label", cid, position=pos
                    )
                    self._markers[cid] = (sphere, label)
                else:
                    sphere, label = self._markers[cid]
                    if not np.allclose(sphere.position, pos):
                        sphere.position = pos
                        label.position = pos

    @property
    def shown(self) -> int:
        """Number of skills in the displayed cloud."""
        return len(self.shown_rows) if self.snap is not None else 0
