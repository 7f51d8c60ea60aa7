"""Issue 16: the replay's MCAP carries the A1 in Foxglove's schemas.

A real A1 collector publishes chunks over a real Zenoh router; the learner's ReplayWriter writes
them; the segment is read back with the MCAP reader and the protobuf schemas embedded in the
file (not this project's classes). Every A1 link has a frame transform at every recorded row
time, and composing them gives the link poses PyBullet computes for the recorded state.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
import zenoh
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from proto import codec
from proto import ursa_pb2 as pb
from proto.topics import Topics
from services.collector.service import Collector, CollectorArgs
from services.common.bus import open_session
from services.common.config import BusConfig, RunConfig
from services.learner.foxglove import a1_urdf_path
from services.learner.replay_store import ReplayWriter, read_segment
from services.stack import Proc, free_port, wait_port
from ursa.config import preset
from ursa.envs.a1 import JOINT_NAMES, OBS_LAYOUT

STEPS = 120


@pytest.fixture(scope="module")
def a1_chunks(tmp_path_factory: pytest.TempPathFactory) -> list[pb.TransitionChunk]:
    """The chunks of a real A1 collector, as they cross the bus."""
    tmp = tmp_path_factory.mktemp("fox")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = Proc("router", ["-m", "services.router", "--listen", endpoint], tmp)
    got: list[pb.TransitionChunk] = []
    lock = threading.Lock()
    try:
        wait_port(port)
        bus = BusConfig(router=endpoint, listen=endpoint)
        cfg = preset("tiny", "a1")
        session = open_session(bus)
        run = RunConfig("fox", tmp / "runs")

        def on(sample: zenoh.Sample) -> None:
            with lock:
                got.append(codec.decode(pb.TransitionChunk, sample.payload.to_bytes()))

        sub = session.declare_subscriber(Topics("fox").transitions("c0"), on)
        c = Collector(CollectorArgs(core=cfg, bus=bus, run=run, collector_id="c0", max_steps=STEPS))
        try:
            c.run()
        finally:
            c.close()
        deadline = 50
        while deadline and sum(x.obs.shape[0] for x in got) < STEPS:
            threading.Event().wait(0.1)
            deadline -= 1
        sub.undeclare()
        session.close()
    finally:
        router.stop()
    with lock:
        return sorted(got, key=lambda x: x.seq)


def _decoded(path: Path, topic_prefix: str) -> list[tuple[str, int, object]]:
    """(topic, log time, message decoded with the file's own schema) of matching messages."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (ch.topic, m.log_time, dec)
            for _s, ch, m, dec in reader.iter_decoded_messages(log_time_order=True)
            if ch.topic.startswith(topic_prefix)
        ]


def _pybullet_links(base_pose: np.ndarray, q: np.ndarray) -> dict[str, np.ndarray]:
    """World transforms (4, 4) of every A1 link by PyBullet, at a base (centre-of-mass) pose
    (7,) and joint angles (12,) set directly."""
    cid = p.connect(p.DIRECT)
    try:
        robot = p.loadURDF(a1_urdf_path(), flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        p.resetBasePositionAndOrientation(robot, base_pose[:3], base_pose[3:], physicsClientId=cid)
        ids = {
            p.getJointInfo(robot, i, physicsClientId=cid)[1].decode(): i
            for i in range(p.getNumJoints(robot, physicsClientId=cid))
        }
        for name, angle in zip(JOINT_NAMES, q, strict=True):
            p.resetJointState(robot, ids[name], float(angle), physicsClientId=cid)
        out = {}
        for i in range(p.getNumJoints(robot, physicsClientId=cid)):
            link = p.getJointInfo(robot, i, physicsClientId=cid)[12].decode()
            s = p.getLinkState(robot, i, computeForwardKinematics=True, physicsClientId=cid)
            m = np.eye(4)
            m[:3, :3] = np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
            m[:3, 3] = s[4]
            out[link] = m
        return out
    finally:
        p.disconnect(physicsClientId=cid)


def _mat(tf: object) -> np.ndarray:
    t, r = tf.translation, tf.rotation  # type: ignore[attr-defined]
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    m[:3, 3] = [t.x, t.y, t.z]
    return m


def test_replay_segment_has_every_a1_link_frame_at_the_recorded_times(
    a1_chunks: list[pb.TransitionChunk], tmp_path: Path
) -> None:
    assert sum(c.obs.shape[0] for c in a1_chunks) == STEPS
    w = ReplayWriter(tmp_path / "replay")
    for c in a1_chunks:
        w.write(c)
    w.close()
    (seg,) = sorted((tmp_path / "replay").glob("segment-*.mcap"))

    # the learner reads back exactly its chunks; the robot's view does not disturb it
    back = list(read_segment(seg))
    assert [c.seq for c in back] == [c.seq for c in a1_chunks]
    assert back[0].SerializeToString() == a1_chunks[0].SerializeToString()

    stamps = np.concatenate([codec.from_array(c.stamp) for c in a1_chunks])
    poses = np.concatenate([codec.from_array(c.base_pose) for c in a1_chunks]).astype(float)
    obs = np.concatenate([codec.from_array(c.obs) for c in a1_chunks]).astype(float)
    assert np.all(np.diff(stamps) > 0)
    times = (stamps * 1e9).astype(np.int64)

    tfs = [(t, m) for topic, t, m in _decoded(seg, "/robot/c0/tf")]
    assert [t for t, _ in tfs] == times.tolist()
    truth_links = set(_pybullet_links(poses[0], obs[0, :12])) | {"trunk"}
    assert len(truth_links) == 22
    feet = []
    for k in (0, 37, STEPS - 1):  # first, a middle and the last row
        t, msg = tfs[k]
        assert type(msg).DESCRIPTOR.full_name == "foxglove.FrameTransforms"  # type: ignore[attr-defined]
        by_child = {}
        for tf in msg.transforms:  # type: ignore[attr-defined]
            assert tf.timestamp.ToNanoseconds() == t
            by_child[tf.child_frame_id] = tf
        assert set(by_child) == {f"c0/{n}" for n in truth_links}

        def world(frame: str, by_child: dict[str, object] = by_child) -> np.ndarray:
            tf = by_child[frame]
            parent = tf.parent_frame_id  # type: ignore[attr-defined]
            return _mat(tf) if parent == "world" else world(parent) @ _mat(tf)

        truth = _pybullet_links(poses[k], obs[k, OBS_LAYOUT["joint_pos"]])
        for link, m in truth.items():
            np.testing.assert_allclose(world(f"c0/{link}"), m, atol=1e-5, err_msg=link)
        feet.append(world("c0/FR_toe")[:3, 3])
    # the robot moves in the replay: its foot is elsewhere at each of those rows
    assert min(np.linalg.norm(a - b) for a, b in ((feet[0], feet[1]), (feet[1], feet[2]))) > 1e-3

    js = _decoded(seg, "/robot/c0/joint_states")
    assert [t for _, t, _ in js] == times.tolist()
    _, _, last = js[-1]
    assert [j.name for j in last.joints] == list(JOINT_NAMES)  # type: ignore[attr-defined]
    np.testing.assert_allclose(
        [j.position for j in last.joints],  # type: ignore[attr-defined]
        obs[-1, OBS_LAYOUT["joint_pos"]],
        atol=1e-6,
    )
    np.testing.assert_allclose(
        [j.velocity for j in last.joints],  # type: ignore[attr-defined]
        obs[-1, OBS_LAYOUT["joint_vel"]],
        atol=1e-5,
    )

    (model,) = _decoded(seg, "/robot/c0/model")
    _, t0, scene = model
    assert t0 == times[0]
    ents = {e.frame_id: e for e in scene.entities}  # type: ignore[attr-defined]
    assert {"c0/trunk", "c0/FR_hip", "c0/FR_upper", "c0/FR_lower"} <= set(ents)
    assert all(
        e.frame_locked and e.models and e.models[0].data[:4] == b"glTF" for e in ents.values()
    )


def test_a_chunk_without_a_body_writes_no_robot_view(tmp_path: Path) -> None:
    chunk = pb.TransitionChunk(
        header=codec.header("r", "collector/p0"),
        collector_id="p0",
        obs=codec.to_array(np.zeros((5, 4), np.float32)),
        stamp=codec.to_array(np.arange(1.0, 6.0)),
    )
    w = ReplayWriter(tmp_path)
    w.write(chunk)
    w.close()
    (seg,) = tmp_path.glob("segment-*.mcap")
    assert {topic for topic, _, _ in _decoded(seg, "/")} == {"/transitions/p0"}
