"""A live Unitree A1 (``pybullet_data/a1/a1.urdf``) mirroring one collector's joints and base pose.

Collector stats carry ``arrays["joint_angles"]`` (12,) in the env's ``JOINT_NAMES`` order,
``arrays["base_position"]`` (3,) and ``arrays["base_orientation"]`` (4,) as a PyBullet (x, y, z, w)
quaternion; viser wants (w, x, y, z). Without them (the point env, or an A1 env that does not
report them) the robot stands in its default pose and a note says why. With "follow" on, the
base's x, y are dropped so that a robot that walked far stays in view.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import viser

from services.common.live import CollectorInfo, StatsEntry

log = logging.getLogger(__name__)

JOINT_NAMES: tuple[str, ...] = tuple(
    f"{leg}_{part}_joint" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "upper", "lower")
)
"""Order of ``joint_angles`` (``ursa.envs.a1.JOINT_NAMES``; repeated here so that the dashboard
does not import PyBullet)."""
STANDING = np.tile([0.0, 0.9, -1.8], 4)
"""The A1's standing pose (``A1Config.standing_pose`` per leg)."""
DEFAULT_BASE = (0.0, 0.0, 0.3)


def a1_urdf_path() -> Path | None:
    try:
        import pybullet_data
    except ImportError:
        return None
    p = Path(pybullet_data.getDataPath()) / "a1" / "a1.urdf"
    return p if p.exists() else None


def xyzw_to_wxyz(q: np.ndarray) -> tuple[float, float, float, float]:
    """PyBullet (x, y, z, w) -> viser (w, x, y, z), normalized; identity if degenerate."""
    q = np.asarray(q, np.float64)
    n = float(np.linalg.norm(q))
    if q.shape != (4,) or not np.isfinite(n) or n < 1e-9:
        return (1.0, 0.0, 0.0, 0.0)
    x, y, z, w = q / n
    return (float(w), float(x), float(y), float(z))


def robot_pose(
    stats: StatsEntry | None, follow: bool
) -> tuple[np.ndarray | None, tuple[float, float, float], tuple[float, float, float, float]]:
    """(joint angles (12,) or None, base position, base wxyz) from a collector's stats."""
    if stats is None:
        return None, DEFAULT_BASE, (1.0, 0.0, 0.0, 0.0)
    q = stats.arrays.get("joint_angles")
    if q is not None and (q.shape != (len(JOINT_NAMES),) or not np.all(np.isfinite(q))):
        q = None
    pos = stats.arrays.get("base_position")
    if pos is None or pos.shape != (3,) or not np.all(np.isfinite(pos)):
        p = DEFAULT_BASE
    else:
        p = (0.0, 0.0, float(pos[2])) if follow else (float(pos[0]), float(pos[1]), float(pos[2]))
    orn = stats.arrays.get("base_orientation")
    wxyz = xyzw_to_wxyz(orn) if orn is not None else (1.0, 0.0, 0.0, 0.0)
    return (None if q is None else np.asarray(q, np.float64)), p, wxyz


class RobotPanel:
    """Collector picker, the URDF model and a note on where the pose comes from."""

    def __init__(self, server: viser.ViserServer, load_meshes: bool = True) -> None:
        self.server = server
        gui = server.gui
        self.collector = gui.add_dropdown(
            "collector", ("(none)",), initial_value="(none)", hint="Whose joints the A1 mirrors"
        )
        self.follow = gui.add_checkbox("follow", True, hint="Keep the base above the origin")
        self.note = gui.add_markdown("*no collector yet: the A1 stands in its default pose*")
        self.root = server.scene.add_frame("/robot", show_axes=False, position=DEFAULT_BASE)
        server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25)
        self.urdf = None
        self._index: np.ndarray | None = None
        self._last_stamp: float | None = None
        self.updates = 0
        path = a1_urdf_path()
        if path is None:
            self.note.content = "*pybullet_data has no a1/a1.urdf: no robot view*"
            return
        try:
            import yourdfpy
            from viser.extras import ViserUrdf

            urdf = yourdfpy.URDF.load(
                str(path), build_scene_graph=load_meshes, load_meshes=load_meshes
            )
            self.urdf = ViserUrdf(server, urdf, root_node_name="/robot", load_meshes=load_meshes)
            names = list(self.urdf.get_actuated_joint_names())
            self._index = np.array([JOINT_NAMES.index(n) for n in names])
            self.urdf.update_cfg(STANDING[self._index])
        except Exception as e:  # a broken mesh must not take the dashboard down
            log.exception("cannot load the A1 URDF")
            self.note.content = f"*cannot load the A1 URDF: {e}*"
            self.urdf = None

    def set_collectors(self, ids: list[str]) -> None:
        opts = tuple(ids) if ids else ("(none)",)
        if tuple(self.collector.options) != opts:
            current = self.collector.value
            self.collector.options = opts
            self.collector.value = current if current in opts else opts[0]  # type: ignore[misc]

    def update(self, collectors: list[CollectorInfo]) -> bool:
        """Mirror the selected collector's latest pose; returns True if the model moved."""
        by_id = {c.id: c for c in collectors if c.alive}
        self.set_collectors(sorted(by_id))
        cid = str(self.collector.value)
        c = by_id.get(cid)
        stats = c.stats if c is not None else None
        if stats is not None and stats.stamp == self._last_stamp:
            return False
        self._last_stamp = stats.stamp if stats is not None else None
        q, pos, wxyz = robot_pose(stats, bool(self.follow.value))
        if c is None:
            note = "*no collector yet: the A1 stands in its default pose*"
        elif q is None:
            env = stats.labels.get("env", "?") if stats is not None else "?"
            note = f"collector **{cid}** (env `{env}`) reports no joint angles: default pose shown"
        else:
            damage = stats.labels.get("damage", "none") if stats is not None else "none"
            note = f"mirroring **{cid}** (damage: {damage})"
        with self.server.atomic():
            if self.urdf is not None and self._index is not None:
                self.urdf.update_cfg((STANDING if q is None else q)[self._index])
            self.root.position = pos
            self.root.wxyz = wxyz
            if self.note.content != note and self.urdf is not None:
                self.note.content = note
        self.updates += 1
        return True
