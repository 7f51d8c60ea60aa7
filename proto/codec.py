"""Encoding and checked decoding of bus messages.

Every payload is a protobuf message from ``ursa.proto`` whose ``header.schema_version`` must equal
``SCHEMA_VERSION``. ``decode`` raises ``BadMessage`` (never anything else) on a payload that is
oversized, does not parse, carries another schema version, or holds an array whose bytes do not
match its dtype and shape; receivers count and drop those.
"""

from __future__ import annotations

import time
from typing import TypeVar

import numpy as np
from google.protobuf.message import DecodeError, Message

from proto import ursa_pb2 as pb

SCHEMA_VERSION = 1
"""Bumped on any incompatible change of ``ursa.proto``."""

MAX_PAYLOAD_BYTES = 64 * 1024 * 1024
"""Larger payloads are rejected before parsing."""

_ALLOWED_DTYPES = frozenset(
    np.dtype(t).str for t in ("f2", "f4", "f8", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "?")
)

M = TypeVar("M", bound=Message)


class BadMessage(ValueError):
    """A payload that cannot be accepted; the reason is the message."""


def to_array(x: np.ndarray) -> pb.Array:
    """numpy array -> ``Array`` (little-endian, C order)."""
    a = np.ascontiguousarray(x)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    return pb.Array(dtype=a.dtype.str, shape=list(a.shape), data=a.tobytes())


def from_array(msg: pb.Array) -> np.ndarray:
    """``Array`` -> read-only numpy array; raises ``BadMessage`` if inconsistent."""
    if msg.dtype not in _ALLOWED_DTYPES:
        raise BadMessage(f"array dtype {msg.dtype!r} not allowed")
    dt = np.dtype(msg.dtype)
    shape = tuple(int(s) for s in msg.shape)
    if any(s < 0 for s in shape):
        raise BadMessage(f"negative array shape {shape}")
    n = int(np.prod(shape, dtype=np.int64)) if shape else 1
    if n * dt.itemsize != len(msg.data):
        raise BadMessage(f"array of shape {shape} and dtype {dt} needs {n * dt.itemsize} bytes, "
                         f"got {len(msg.data)}")
    return np.frombuffer(msg.data, dtype=dt).reshape(shape)


def header(run_id: str, sender: str) -> pb.Header:
    """A fresh header stamped now."""
    return pb.Header(schema_version=SCHEMA_VERSION, run_id=run_id, stamp=time.time(), sender=sender)


def encode(msg: Message) -> bytes:
    """Serialize a message (its header must already be set)."""
    return msg.SerializeToString()


def decode(cls: type[M], payload: bytes | bytearray | memoryview, run_id: str | None = None) -> M:
    """Parse ``payload`` as ``cls`` and check its header; raises ``BadMessage``."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise BadMessage(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    msg = cls()
    try:
        msg.ParseFromString(bytes(payload))
    except (DecodeError, RuntimeWarning, ValueError) as e:
        raise BadMessage(f"cannot parse {cls.__name__}: {e}") from e
    hdr = getattr(msg, "header", None)
    if hdr is None or not msg.HasField("header"):  # type: ignore[arg-type]
        raise BadMessage(f"{cls.__name__} without header")
    if hdr.schema_version != SCHEMA_VERSION:
        raise BadMessage(
            f"{cls.__name__} schema version {hdr.schema_version}, expected {SCHEMA_VERSION}"
        )
    if run_id is not None and hdr.run_id != run_id:
        raise BadMessage(f"{cls.__name__} from run {hdr.run_id!r}, expected {run_id!r}")
    return msg
