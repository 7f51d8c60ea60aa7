"""Every bus message round-trips through its schema; bad payloads raise BadMessage only."""

from __future__ import annotations

import filecmp
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from proto import codec
from proto import ursa_pb2 as pb

ROOT = Path(__file__).resolve().parents[2]


def _arr(shape: tuple[int, ...], dtype: str = "f4") -> np.ndarray:
    return np.arange(int(np.prod(shape)), dtype=dtype).reshape(shape)


def _examples() -> list[pb.Message]:  # type: ignore[name-defined]
    h = codec.header("run1", "test/0")
    return [
        pb.TransitionChunk(
            header=h,
            collector_id="c0",
            seq=3,
            first_step=150,
            policy_version=2,
            incarnation=1,
            obs=codec.to_array(_arr((50, 40))),
            action=codec.to_array(_arr((50, 12))),
            reward=codec.to_array(_arr((50,))),
            cost=codec.to_array(_arr((50,))),
            safe=codec.to_array(np.ones(50, bool)),
            features=codec.to_array(_arr((50, 13))),
            skill=codec.to_array(_arr((50, 3))),
            task="forward",
            damage="front_hip",
        ),
        pb.SafeFeatures(header=h, collector_id="c1", seq=9, features=codec.to_array(_arr((7, 3)))),
        pb.SkillRequest(header=h, n=4, has_seed=True, seed=42),
        pb.SkillReply(
            header=h,
            skills=codec.to_array(_arr((4, 3))),
            delta=0.5,
            encoder_version=2,
            snapshot_version=11,
        ),
        pb.RepertoireSnapshot(
            header=h,
            version=5,
            skills=codec.to_array(_arr((10, 3))),
            ids=codec.to_array(_arr((10,), "i8")),
            ages=codec.to_array(_arr((10,), "i8")),
            nn_dist=codec.to_array(_arr((10,))),
            cov=codec.to_array(np.eye(3)),
            inputs=codec.to_array(_arr((10, 13))),
            delta=1.5,
            entropy_bound=-2.0,
            encoder_version=1,
            commits=100,
            capacity=5000,
            n_z=100,
        ),
        pb.PolicyWeights(
            header=h, version=7, safetensors=b"\x00\x01", config_hash="abc", updates=1000
        ),
        pb.EncoderWeights(header=h, version=2, safetensors=b"\x02", config_hash="abc"),
        pb.Stats(
            header=h,
            service="collector",
            id="c0",
            scalars={"steps": 10.0},
            labels={"damage": "none"},
            arrays={"skill": codec.to_array(_arr((3,)))},
        ),
        pb.EvaluateRequest(header=h, skill=codec.to_array(_arr((3,))), steps=250, damage=""),
        pb.EvaluateReply(
            header=h,
            achieved=codec.to_array(_arr((3,))),
            distance=0.1,
            delta=0.3,
            ret=12.0,
            violations=1,
            steps=250,
            policy_version=3,
        ),
        pb.AdaptRequest(
            header=h, damage="front_hip", frozen_joints=[4, 7], budget=20, alpha=0.9, kappa=0.05
        ),
        pb.AdaptJob(
            header=h,
            job_id="0123456789abcdef",
            evaluator_id="eval",
            state="adapting",
            request=pb.AdaptRequest(header=h, budget=5),
            map_skills=codec.to_array(_arr((4, 3))),
            map_ids=codec.to_array(_arr((4,), "i8")),
            map_returns=codec.to_array(_arr((4,), "f8")),
            mapped=4,
            trials=[
                pb.AdaptJob.Trial(
                    row=1, skill_id=2, skill=codec.to_array(_arr((3,))), ret=1.0, predicted=0.5
                )
            ],
            chosen_skill_id=2,
            predicted_mean=codec.to_array(_arr((4,), "f8")),
        ),
        pb.AdaptQuery(header=h, job_id="0123456789abcdef"),
    ]


@pytest.mark.parametrize("msg", _examples(), ids=lambda m: type(m).__name__)
def test_every_message_round_trips(msg: pb.Message) -> None:  # type: ignore[name-defined]
    data = codec.encode(msg)
    back = codec.decode(type(msg), data, run_id="run1")
    assert back == msg
    for field, value in back.ListFields():
        if isinstance(value, pb.Array):
            orig = codec.from_array(getattr(msg, field.name))
            np.testing.assert_array_equal(codec.from_array(value), orig)


def test_every_message_of_the_schema_is_covered() -> None:
    covered = {type(m).__name__ for m in _examples()}
    defined = set(pb.DESCRIPTOR.message_types_by_name) - {"Array", "Header"}
    assert defined == covered


@pytest.mark.parametrize("dtype", ["<f4", "<f8", "<i8", "|b1", "|u1", "<f2"])
def test_array_dtypes_round_trip(dtype: str) -> None:
    x = (np.arange(24) % 3).astype(dtype).reshape(2, 3, 4)
    y = codec.from_array(codec.to_array(x))
    assert y.dtype == x.dtype and y.shape == x.shape
    np.testing.assert_array_equal(x, y)


def test_big_endian_arrays_are_sent_little_endian() -> None:
    x = np.arange(5, dtype=">f4")
    msg = codec.to_array(x)
    assert msg.dtype == "<f4"
    np.testing.assert_array_equal(codec.from_array(msg), x)


def test_garbage_is_bad_message() -> None:
    with pytest.raises(codec.BadMessage):
        codec.decode(pb.TransitionChunk, b"\xff\xff\xff\xff not a protobuf")


def test_missing_header_is_bad_message() -> None:
    with pytest.raises(codec.BadMessage, match="without header"):
        codec.decode(pb.SafeFeatures, codec.encode(pb.SafeFeatures(collector_id="c0")))


def test_wrong_schema_version_is_bad_message() -> None:
    msg = pb.SkillRequest(header=codec.header("r", "x"), n=1)
    msg.header.schema_version = codec.SCHEMA_VERSION + 1
    with pytest.raises(codec.BadMessage, match="schema version"):
        codec.decode(pb.SkillRequest, codec.encode(msg))


def test_wrong_run_is_bad_message() -> None:
    msg = pb.SkillRequest(header=codec.header("other", "x"), n=1)
    with pytest.raises(codec.BadMessage, match="from run"):
        codec.decode(pb.SkillRequest, codec.encode(msg), run_id="mine")


def test_oversized_payload_is_rejected_before_parsing() -> None:
    with pytest.raises(codec.BadMessage, match="exceeds"):
        codec.decode(pb.SafeFeatures, b"\x00" * (codec.MAX_PAYLOAD_BYTES + 1))


@pytest.mark.parametrize(
    "arr",
    [
        pb.Array(dtype="<f4", shape=[2, 3], data=b"\x00" * 23),
        pb.Array(dtype="object", shape=[1], data=b"\x00" * 8),
        pb.Array(dtype="<f4", shape=[-1], data=b""),
    ],
    ids=["size-mismatch", "object-dtype", "negative-shape"],
)
def test_inconsistent_arrays_are_bad_message(arr: pb.Array) -> None:
    with pytest.raises(codec.BadMessage):
        codec.from_array(arr)


def test_regenerating_the_schema_changes_nothing(tmp_path: Path) -> None:
    import grpc_tools  # noqa: F401 - a dev dependency: missing, this fails (never a skip)

    shutil.copy(ROOT / "proto" / "ursa.proto", tmp_path / "ursa.proto")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "grpc_tools.protoc",
            f"-I{tmp_path}",
            f"--python_out={tmp_path}",
            f"--pyi_out={tmp_path}",
            str(tmp_path / "ursa.proto"),
        ],
        check=True,
    )
    for name in ("ursa_pb2.py", "ursa_pb2.pyi"):
        assert filecmp.cmp(tmp_path / name, ROOT / "proto" / name, shallow=False), (
            f"proto/{name} is stale: run `make proto` and commit the result"
        )


# ---- integrity: checksums, MACs, frames -----------------------------------------------------

KEY = bytes(range(32))


@pytest.fixture
def no_run_key() -> Iterator[None]:
    before = codec.run_key()
    codec.set_run_key(None)
    yield
    codec.set_run_key(before)


@pytest.mark.parametrize("key", [None, KEY], ids=["checksum", "mac"])
@pytest.mark.parametrize("msg", _examples(), ids=lambda m: type(m).__name__)
def test_every_message_round_trips_framed(
    msg: pb.Message,  # type: ignore[name-defined]
    key: bytes | None,
    no_run_key: None,
) -> None:
    data = codec.encode(msg, key=key)
    f = codec.read_frame(data)
    assert f.algorithm == (codec.MAC if key else codec.CHECKSUM)
    assert f.sender == "test/0" and f.body == msg.SerializeToString()
    assert codec.decode(type(msg), data, run_id="run1", key=key) == msg


@pytest.mark.parametrize("key", [None, KEY], ids=["checksum", "mac"])
def test_every_flipped_byte_fails_integrity(key: bytes | None, no_run_key: None) -> None:
    msg = _examples()[1]
    data = codec.encode(msg, key=key)
    failures = 0
    for i in range(len(data)):
        bad = bytearray(data)
        bad[i] ^= 0x5A
        with pytest.raises(codec.BadMessage):
            codec.decode(pb.SafeFeatures, bytes(bad), key=key)
        try:
            codec.verify(pb.SafeFeatures, bytes(bad), key=key)
        except codec.IntegrityError:
            failures += 1
    # every byte is covered by the frame check (a flipped sender fails the tag too)
    assert failures == len(data)


def test_unframed_protobuf_fails_integrity(no_run_key: None) -> None:
    msg = _examples()[1]
    with pytest.raises(codec.IntegrityError, match="not a URSA frame"):
        codec.decode(pb.SafeFeatures, msg.SerializeToString())


def test_a_frame_cannot_pass_as_another_type(no_run_key: None) -> None:
    # SafeFeatures and SkillRequest bodies both start with a header; the tag names the type
    data = codec.encode(pb.SkillRequest(header=codec.header("r", "x/0"), n=3))
    with pytest.raises(codec.IntegrityError, match="checksum"):
        codec.decode(pb.SafeFeatures, data)


def test_with_a_run_key_checksums_and_foreign_macs_are_refused(no_run_key: None) -> None:
    msg = _examples()[2]
    codec.set_run_key(KEY)
    good = codec.encode(msg)
    assert codec.read_frame(good).algorithm == codec.MAC
    assert codec.decode(pb.SkillRequest, good) == msg
    with pytest.raises(codec.IntegrityError, match="no MAC"):
        codec.decode(
            pb.SkillRequest,
            codec.frame(msg.SerializeToString(), msg.DESCRIPTOR.full_name, "test/0"),
        )
    with pytest.raises(codec.IntegrityError, match="fails its MAC"):
        codec.decode(pb.SkillRequest, codec.encode(msg, key=b"k" * 32))
    codec.set_run_key(None)
    with pytest.raises(codec.IntegrityError, match="no run key"):
        codec.decode(pb.SkillRequest, good)


def test_the_header_sender_must_be_the_frame_sender(no_run_key: None) -> None:
    msg = pb.SkillRequest(header=codec.header("r", "learner/main"), n=1)
    forged = codec.frame(msg.SerializeToString(), msg.DESCRIPTOR.full_name, "collector/c0")
    with pytest.raises(codec.BadMessage, match="not the frame's"):
        codec.decode(pb.SkillRequest, forged)
    assert codec.claimed_sender(forged) == "collector/c0"
    assert codec.claimed_sender(b"junk") == "?"


def test_short_run_keys_are_refused() -> None:
    with pytest.raises(ValueError, match="16 bytes"):
        codec.set_run_key(b"short")
