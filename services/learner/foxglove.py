"""The A1 of a replay chunk in Foxglove's own schemas (``foxglove-schemas-protobuf``).

For every row of a ``TransitionChunk`` that carries the robot's base pose (``base_pose``, A1
collectors record it) and row times (``stamp``), :class:`RobotView` makes, at that row's time:

- ``/robot/<collector>/tf``: ``foxglove.FrameTransforms``: ``world`` -> ``<collector>/trunk`` (the
  base) and, for every joint of the A1's URDF (``pybullet_data/a1/a1.urdf``; revolute and fixed),
  parent link -> child link at the recorded joint angles (forward kinematics of the URDF as
  parsed by yourdfpy), so every one of the 22 links has a frame;
- ``/robot/<collector>/joint_states``: ``foxglove.JointStates``: the 12 actuated joints' angle and
  velocity (from the observation, ``ursa.envs.a1.OBS_LAYOUT``);

and, once per segment and collector, ``/robot/<collector>/model``: a ``foxglove.SceneUpdate``
with one frame-locked entity per link that has a mesh (the URDF's meshes as embedded glTF), so
Foxglove's 3D panel draws the robot on those frames with no URDF set up. Frames are prefixed
with the collector id so that several robots share one scene. See docs/foxglove.md.

PyBullet's base pose is the trunk's inertial frame (centre of mass, principal axes); the URDF's
trunk frame is that pose times the inverse of the inertial frame, which PyBullet reports.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.JointState_pb2 import JointState
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.ModelPrimitive_pb2 import ModelPrimitive
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.message import Message
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

from proto import codec
from proto import ursa_pb2 as pb
from ursa.envs.a1 import JOINT_NAMES, OBS_LAYOUT

WORLD = "world"


def a1_urdf_path() -> str:
    import pybullet_data

    return os.path.join(pybullet_data.getDataPath(), "a1", "a1.urdf")


@functools.cache
def base_inertial_frame(urdf_path: str) -> np.ndarray:
    """PyBullet's base frame (4, 4) in the URDF's root link frame, as ``ursa.envs.a1`` loads the
    robot (inertia from the file). PyBullet diagonalises the inertia tensor, so this frame is the
    URDF's inertial origin turned onto the principal axes: only PyBullet knows it exactly."""
    import pybullet as p

    cid = p.connect(p.DIRECT)
    try:
        robot = p.loadURDF(urdf_path, flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        pos, orn = p.getDynamicsInfo(robot, -1, physicsClientId=cid)[3:5]
    finally:
        p.disconnect(physicsClientId=cid)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(orn).as_matrix()
    m[:3, 3] = pos
    return m


@dataclass(frozen=True)
class Joint:
    """One URDF joint: parent and child link, origin (4, 4), type, unit axis (3,), and the
    column of the joint's angle in ``JOINT_NAMES`` (-1 when it does not move)."""

    name: str
    parent: str
    child: str
    origin: np.ndarray
    kind: str
    axis: np.ndarray
    column: int


class A1Kinematics:
    """Forward kinematics of the A1's URDF: link -> parent transforms at given joint angles."""

    def __init__(self, urdf_path: str | None = None) -> None:
        import yourdfpy

        self.path = urdf_path or a1_urdf_path()
        urdf = yourdfpy.URDF.load(
            self.path,
            load_meshes=False,
            build_scene_graph=False,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
        )
        self.urdf = urdf
        joints = list(urdf.robot.joints)
        children = {j.child for j in joints}
        roots = [lk.name for lk in urdf.robot.links if lk.name not in children]
        if len(roots) != 1:
            raise ValueError(f"expected one root link, found {roots}")
        self.root: str = roots[0]
        col = {n: i for i, n in enumerate(JOINT_NAMES)}
        self.joints: list[Joint] = []
        # parents before children, so that composing in list order reaches every link
        known = {self.root}
        while joints:
            ready = [j for j in joints if j.parent in known]
            if not ready:
                raise ValueError("URDF joints do not form a tree")
            for j in ready:
                if j.type not in ("revolute", "continuous", "fixed"):
                    raise ValueError(f"unsupported joint type {j.type} of {j.name}")
                moves = j.type != "fixed"
                if moves and j.name not in col:
                    raise ValueError(f"URDF joint {j.name} is not one of JOINT_NAMES")
                origin = np.eye(4) if j.origin is None else np.asarray(j.origin, float)
                axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
                self.joints.append(
                    Joint(
                        j.name,
                        j.parent,
                        j.child,
                        origin,
                        j.type,
                        axis / np.linalg.norm(axis),
                        col[j.name] if moves else -1,
                    )
                )
                known.add(j.child)
                joints.remove(j)
        self.links: list[str] = [self.root, *(j.child for j in self.joints)]
        self.root_from_com = np.linalg.inv(base_inertial_frame(self.path))
        """The root link's frame in PyBullet's base frame (its inertial frame)."""

    def local(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Child-in-parent transforms (T, 4, 4) of every joint, by child link, for joint angles
        q (T, 12) in ``JOINT_NAMES`` order."""
        q = np.asarray(q, float)
        out: dict[str, np.ndarray] = {}
        for j in self.joints:
            m = np.broadcast_to(j.origin, (len(q), 4, 4)).copy()
            if j.column >= 0:
                r = Rotation.from_rotvec(q[:, j.column, None] * j.axis).as_matrix()
                m[:, :3, :3] = j.origin[:3, :3] @ r
            out[j.child] = m
        return out

    def root_pose(self, base_pose: np.ndarray) -> np.ndarray:
        """The root link's world transforms (T, 4, 4) from PyBullet base poses (T, 7):
        centre-of-mass position xyz and quaternion xyzw."""
        base_pose = np.asarray(base_pose, float)
        m = np.zeros((len(base_pose), 4, 4))
        m[:, :3, :3] = Rotation.from_quat(base_pose[:, 3:7]).as_matrix()
        m[:, :3, 3] = base_pose[:, :3]
        m[:, 3, 3] = 1.0
        return m @ self.root_from_com

    def world(self, base_pose: np.ndarray, q: np.ndarray) -> dict[str, np.ndarray]:
        """World transforms (T, 4, 4) of every link."""
        out = {self.root: self.root_pose(base_pose)}
        loc = self.local(q)
        for j in self.joints:
            out[j.child] = out[j.parent] @ loc[j.child]
        return out


@functools.cache
def kinematics() -> A1Kinematics:
    return A1Kinematics()


def _timestamp(msg_ts: object, ns: int) -> None:
    msg_ts.FromNanoseconds(ns)  # type: ignore[attr-defined]


def robot_rows(chunk: pb.TransitionChunk) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(stamps (T,) ns, base poses (T, 7), observations (T, 46)) of a chunk that carries the A1's
    state, else None (point env, an older replay, or malformed arrays)."""
    if not chunk.HasField("base_pose") or not chunk.HasField("stamp"):
        return None
    try:
        pose = codec.from_array(chunk.base_pose).astype(float)
        stamp = codec.from_array(chunk.stamp).astype(float)
        obs = codec.from_array(chunk.obs).astype(float)
    except codec.BadMessage:
        return None
    n = len(obs)
    if (
        pose.shape != (n, 7)
        or stamp.shape != (n,)
        or obs.ndim != 2
        or obs.shape[1] < OBS_LAYOUT["joint_vel"].stop
    ):
        return None
    if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(stamp)) and np.all(stamp > 0)):
        return None
    return (stamp * 1e9).astype(np.int64), pose, obs


class RobotView:
    """Foxglove messages of the robot for each chunk; see the module docstring."""

    def __init__(self, kin: A1Kinematics | None = None, meshes: bool = True) -> None:
        self.kin = kin or kinematics()
        self.meshes = meshes

    def messages(
        self, chunk: pb.TransitionChunk, with_model: bool = False
    ) -> Iterator[tuple[str, int, Message]]:
        """(topic, log time ns, message) of every row of ``chunk`` (none without robot state);
        ``with_model``: the model's SceneUpdate first."""
        rows = robot_rows(chunk)
        if rows is None:
            return
        stamps, pose, obs = rows
        cid = chunk.collector_id
        prefix = f"{cid}/"
        q = obs[:, OBS_LAYOUT["joint_pos"]]
        qd = obs[:, OBS_LAYOUT["joint_vel"]]
        root = self.kin.root_pose(pose)
        loc = self.kin.local(q)
        frames = [(WORLD, self.kin.root, root)] + [
            (prefix + j.parent, j.child, loc[j.child]) for j in self.kin.joints
        ]
        # plain floats, per frame (T, 3) and (T, 4): protobuf setters are the cost here
        parts = [
            (
                parent,
                prefix + child,
                m[:, :3, 3].tolist(),
                Rotation.from_matrix(m[:, :3, :3]).as_quat().tolist(),
            )
            for parent, child, m in frames
        ]
        qs, qds = q.tolist(), qd.tolist()
        if with_model and self.meshes:
            yield f"/robot/{cid}/model", int(stamps[0]), self.model(prefix, int(stamps[0]))
        for i, ns in enumerate(stamps.tolist()):
            ts = Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)
            tf = FrameTransforms(
                transforms=[
                    FrameTransform(
                        timestamp=ts,
                        parent_frame_id=parent,
                        child_frame_id=child,
                        translation=Vector3(x=tr[i][0], y=tr[i][1], z=tr[i][2]),
                        rotation=Quaternion(x=qu[i][0], y=qu[i][1], z=qu[i][2], w=qu[i][3]),
                    )
                    for parent, child, tr, qu in parts
                ]
            )
            yield f"/robot/{cid}/tf", ns, tf
            js = JointStates(
                timestamp=ts,
                joints=[
                    JointState(name=n, position=qs[i][k], velocity=qds[i][k])
                    for k, n in enumerate(JOINT_NAMES)
                ],
            )
            yield f"/robot/{cid}/joint_states", ns, js

    def model(self, prefix: str, ns: int) -> SceneUpdate:
        """One frame-locked entity per link with a mesh, its meshes embedded as glTF."""
        upd = SceneUpdate()
        for link, visuals in _link_meshes(self.kin.path):
            e = SceneEntity(frame_id=prefix + link, id=prefix + link, frame_locked=True)
            _timestamp(e.timestamp, ns)
            for origin, glb, rgba in visuals:
                quat = Rotation.from_matrix(origin[:3, :3]).as_quat()
                pose = Pose(
                    position=Vector3(x=origin[0, 3], y=origin[1, 3], z=origin[2, 3]),
                    orientation=Quaternion(x=quat[0], y=quat[1], z=quat[2], w=quat[3]),
                )
                e.models.append(
                    ModelPrimitive(
                        pose=pose,
                        scale=Vector3(x=1.0, y=1.0, z=1.0),
                        color=Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
                        override_color=True,
                        media_type="model/gltf-binary",
                        data=glb,
                    )
                )
            upd.entities.append(e)
        return upd


Visual = tuple[np.ndarray, bytes, tuple[float, float, float, float]]
"""A link's mesh: its origin (4, 4) in the link frame, glTF bytes, and rgba."""


@functools.cache
def _link_meshes(urdf_path: str) -> tuple[tuple[str, tuple[Visual, ...]], ...]:
    """(link, ((visual origin (4, 4), glTF bytes, rgba), ...)) of every link with a mesh visual.
    Texture coordinates are dropped (one colour per link) so that vertices merge: the trunk goes
    from 1.6 MB to a few hundred kB."""
    import trimesh
    import yourdfpy

    urdf = yourdfpy.URDF.load(
        urdf_path,
        load_meshes=False,
        build_scene_graph=False,
        build_collision_scene_graph=False,
        load_collision_meshes=False,
    )
    base = os.path.dirname(urdf_path)
    cache: dict[str, bytes] = {}
    grey, dark = (0.75, 0.75, 0.78, 1.0), (0.2, 0.2, 0.22, 1.0)
    out: list[tuple[str, tuple[Visual, ...]]] = []
    for link in urdf.robot.links:
        vis: list[Visual] = []
        for v in link.visuals:
            if v.geometry is None or v.geometry.mesh is None:
                continue
            fn = v.geometry.mesh.filename
            key = f"{fn}|{v.geometry.mesh.scale}"
            if key not in cache:
                loaded: Any = trimesh.load(os.path.join(base, fn), force="mesh")
                m = trimesh.Trimesh(vertices=loaded.vertices, faces=loaded.faces, process=True)
                if v.geometry.mesh.scale is not None:
                    m.apply_scale(np.asarray(v.geometry.mesh.scale, float))
                glb = m.export(file_type="glb")
                assert isinstance(glb, bytes)
                cache[key] = glb
            origin = np.eye(4) if v.origin is None else np.asarray(v.origin, float)
            vis.append((origin, cache[key], grey if link.name == "trunk" else dark))
        if vis:
            out.append((link.name, tuple(vis)))
    return tuple(out)
