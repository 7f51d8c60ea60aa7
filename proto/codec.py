"""Encoding and checked decoding of bus messages.

Every payload on the bus is a *frame*: a fixed prefix carrying an integrity tag, then the
serialized protobuf message from ``ursa.proto``::

    b"UF" | version (1 byte) | algorithm (1 byte) | sender length (1 byte) | sender (ASCII)
          | tag (32 bytes) | body (protobuf)

The tag is SHA-256 (algorithm ``CHECKSUM``) or, when the run has a key, HMAC-SHA256 under that
key (algorithm ``MAC``) over ``type name | 0 | sender | 0 | body``: it binds the body to its
message type and to the sender it claims, so a frame cannot be replayed as another type. The
checksum catches corruption; only the MAC stops forgery (anyone can recompute a checksum).
With a run key configured (:func:`set_run_key`), frames without a valid MAC are refused.

``decode`` checks the frame *before* parsing anything, then the header:
``header.schema_version`` must equal ``SCHEMA_VERSION``, ``header.sender`` the frame's sender.
It raises ``BadMessage`` (never anything else) on a payload that is oversized, badly framed,
fails its integrity check (``IntegrityError``, a ``BadMessage``), does not parse, carries another
schema version, or holds an array whose bytes do not match its dtype and shape; receivers count
and drop those.
"""

from __future__ import annotations

import hashlib
import hmac
import threading
import time
from typing import NamedTuple, TypeVar

import numpy as np
from google.protobuf.message import DecodeError, Message

from proto import ursa_pb2 as pb

SCHEMA_VERSION = 1
"""Bumped on any incompatible change of ``ursa.proto``."""

MAX_PAYLOAD_BYTES = 64 * 1024 * 1024
"""Larger payloads are rejected before parsing."""

FRAME_MAGIC = b"UF"
FRAME_VERSION = 1
CHECKSUM = 1
"""Frame algorithm: SHA-256 of the tagged bytes (integrity against corruption only)."""
MAC = 2
"""Frame algorithm: HMAC-SHA256 under the run key (integrity and origin)."""
TAG_BYTES = 32
MAX_SENDER_BYTES = 255

_ALLOWED_DTYPES = frozenset(
    np.dtype(t).str for t in ("f2", "f4", "f8", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "?")
)

M = TypeVar("M", bound=Message)

_key_lock = threading.Lock()
_run_key: bytes | None = None


class BadMessage(ValueError):
    """A payload that cannot be accepted; the reason is the message."""


class IntegrityError(BadMessage):
    """A frame whose tag does not verify, or that lacks the MAC the run requires."""


class Frame(NamedTuple):
    """A frame's prefix as read (unverified) and its body."""

    algorithm: int
    sender: str
    tag: bytes
    body: bytes


def set_run_key(key: bytes | None) -> None:
    """Use ``key`` (≥ 16 bytes) for every later ``encode`` and ``decode`` of this process;
    None: checksums only. Every process of a run sets the same key (``<run>/secrets/bus.key``)."""
    global _run_key
    if key is not None and len(key) < 16:
        raise ValueError(f"a run key needs at least 16 bytes, got {len(key)}")
    with _key_lock:
        _run_key = None if key is None else bytes(key)


def run_key() -> bytes | None:
    """The key set by :func:`set_run_key` (None: checksums only)."""
    return _run_key


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
        raise BadMessage(
            f"array of shape {shape} and dtype {dt} needs {n * dt.itemsize} bytes, "
            f"got {len(msg.data)}"
        )
    return np.frombuffer(msg.data, dtype=dt).reshape(shape)


def header(run_id: str, sender: str) -> pb.Header:
    """A fresh header stamped now."""
    return pb.Header(schema_version=SCHEMA_VERSION, run_id=run_id, stamp=time.time(), sender=sender)


def _tag(algorithm: int, type_name: str, sender: bytes, body: bytes, key: bytes | None) -> bytes:
    parts = (type_name.encode(), b"\0", sender, b"\0", body)
    if algorithm == MAC:
        assert key is not None
        mac = hmac.new(key, digestmod=hashlib.sha256)
        for p in parts:
            mac.update(p)
        return mac.digest()
    h = hashlib.sha256()
    for p in parts:
        h.update(p)
    return h.digest()


def frame(
    body: bytes, type_name: str, sender: str, key: bytes | None = None, algorithm: int | None = None
) -> bytes:
    """Wrap serialized ``body`` of message type ``type_name`` (full name, e.g.
    ``ursa.v1.Stats``) in a frame tagged with a MAC under ``key``, or a checksum without one."""
    s = sender.encode("ascii", "replace")[:MAX_SENDER_BYTES]
    alg = algorithm if algorithm is not None else (MAC if key is not None else CHECKSUM)
    tag = _tag(alg, type_name, s, body, key)
    return b"".join((FRAME_MAGIC, bytes((FRAME_VERSION, alg, len(s))), s, tag, body))


def read_frame(payload: bytes | bytearray | memoryview) -> Frame:
    """Split a frame into its parts without verifying it; raises ``BadMessage``."""
    data = bytes(payload)
    if len(data) > MAX_PAYLOAD_BYTES:
        raise BadMessage(f"payload of {len(data)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    if len(data) < 5 + TAG_BYTES or data[:2] != FRAME_MAGIC:
        raise IntegrityError("not a URSA frame (no integrity prefix)")
    if data[2] != FRAME_VERSION:
        raise IntegrityError(f"frame version {data[2]}, expected {FRAME_VERSION}")
    alg, n = data[3], data[4]
    if alg not in (CHECKSUM, MAC):
        raise IntegrityError(f"unknown frame algorithm {alg}")
    if len(data) < 5 + n + TAG_BYTES:
        raise IntegrityError("truncated frame")
    sender = data[5 : 5 + n].decode("ascii", "replace")
    tag = data[5 + n : 5 + n + TAG_BYTES]
    return Frame(alg, sender, tag, data[5 + n + TAG_BYTES :])


def verify(
    cls: type[Message], payload: bytes | bytearray | memoryview, key: bytes | None = None
) -> Frame:
    """Read and verify the frame of a ``cls`` payload; returns it. With ``key`` (default: the
    run key), only a valid MAC passes; without, a valid checksum. Raises ``IntegrityError``."""
    key = run_key() if key is None else key
    f = read_frame(payload)
    if key is not None and f.algorithm != MAC:
        raise IntegrityError(f"{cls.__name__} from {f.sender!r} carries no MAC; the run has a key")
    if key is None and f.algorithm == MAC:
        raise IntegrityError(
            f"{cls.__name__} from {f.sender!r} carries a MAC; no run key is configured here"
        )
    want = _tag(
        f.algorithm, cls.DESCRIPTOR.full_name, f.sender.encode("ascii", "replace"), f.body, key
    )
    if not hmac.compare_digest(want, f.tag):
        kind = "MAC" if f.algorithm == MAC else "checksum"
        raise IntegrityError(f"{cls.__name__} from {f.sender!r} fails its {kind}")
    return f


def encode(msg: Message, key: bytes | None = None) -> bytes:
    """Serialize a message (its header must already be set) into a frame tagged for the run
    (MAC under ``key``, default the run key; a checksum when there is none)."""
    sender = msg.header.sender if msg.HasField("header") else ""  # type: ignore[attr-defined]
    return frame(
        msg.SerializeToString(), msg.DESCRIPTOR.full_name, sender, run_key() if key is None else key
    )


def decode(
    cls: type[M],
    payload: bytes | bytearray | memoryview,
    run_id: str | None = None,
    key: bytes | None = None,
) -> M:
    """Verify the frame of ``payload``, parse its body as ``cls`` and check its header; raises
    ``BadMessage`` (``IntegrityError`` for a failed integrity check)."""
    f = verify(cls, payload, key)
    msg = cls()
    try:
        msg.ParseFromString(f.body)
    except (DecodeError, RuntimeWarning, ValueError) as e:
        raise BadMessage(f"cannot parse {cls.__name__}: {e}") from e
    hdr = getattr(msg, "header", None)
    if hdr is None or not msg.HasField("header"):  # type: ignore[arg-type]
        raise BadMessage(f"{cls.__name__} without header")
    if hdr.schema_version != SCHEMA_VERSION:
        raise BadMessage(
            f"{cls.__name__} schema version {hdr.schema_version}, expected {SCHEMA_VERSION}"
        )
    if hdr.sender.encode("ascii", "replace")[:MAX_SENDER_BYTES].decode("ascii") != f.sender:
        raise BadMessage(
            f"{cls.__name__} header sender {hdr.sender!r} is not the frame's {f.sender!r}"
        )
    if run_id is not None and hdr.run_id != run_id:
        raise BadMessage(f"{cls.__name__} from run {hdr.run_id!r}, expected {run_id!r}")
    return msg


def claimed_sender(payload: bytes | bytearray | memoryview) -> str:
    """The sender a payload's frame claims (unverified), or ``"?"``: for counting drops per
    publisher."""
    try:
        return read_frame(payload).sender or "?"
    except BadMessage:
        return "?"
