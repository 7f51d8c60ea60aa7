"""The learner's replay on disk: MCAP segments of ``TransitionChunk`` protobuf messages.

Each segment is an MCAP file with the protobuf schemas embedded, so Foxglove (or ``mcap cat``)
opens it. Each chunk and the messages that come with it are written as one compressed MCAP chunk
and flushed at once, so a learner killed with SIGKILL loses nothing it had written: on restart
the unfinished tail segment is read up to its last complete record and a new segment is started.

Beside ``/transitions/<collector>``, chunks of a robot with a body (the A1) also put the robot's
state in Foxglove's schemas on ``/robot/<collector>/...`` (``services.learner.foxglove``): frame
transforms of every link and joint states at each row's time, and the robot's meshes once per
segment, so that Foxglove's 3D panel shows the A1 moving (docs/foxglove.md).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from google.protobuf.message import Message as PbMessage
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from proto import ursa_pb2 as pb
from services.learner.foxglove import RobotView

log = logging.getLogger(__name__)
SEGMENT_GLOB = "segment-*.mcap"


TRANSITIONS_PREFIX = "/transitions/"


def topic_for(collector_id: str) -> str:
    """MCAP topic of one collector's chunks."""
    return f"{TRANSITIONS_PREFIX}{collector_id}"


class ProtobufMcap:
    """An MCAP writer of protobuf messages (one channel per topic, schemas embedded) whose
    :meth:`flush` ends the current chunk: what was written before a flush survives a crash."""

    def __init__(self, f: BinaryIO) -> None:
        # chunks end at flush(), not at a size: the size limit only bounds a burst
        self._w = McapWriter(f, chunk_size=64 * 1024 * 1024, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="ursa replay")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}

    def write(self, topic: str, msg: PbMessage, log_time: int, sequence: int = 0) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            name = msg.DESCRIPTOR.full_name
            if name not in self._schemas:
                self._schemas[name] = register_schema(self._w, type(msg))
            ch = self._w.register_channel(
                topic=topic,
                message_encoding=MessageEncoding.Protobuf,
                schema_id=self._schemas[name],
            )
            self._channels[topic] = ch
        self._w.add_message(
            channel_id=ch,
            log_time=log_time,
            data=msg.SerializeToString(),
            publish_time=log_time,
            sequence=sequence,
        )

    def flush(self) -> None:
        self._w.flush()

    def finish(self) -> None:
        self._w.finish()


class ReplayWriter:
    """Appends chunks to the current segment; rotates after ``segment_chunks`` messages.

    ``robot_view``: also write the robot's state in Foxglove's schemas (see the module docstring).
    """

    def __init__(
        self,
        directory: Path,
        segment_chunks: int = 2000,
        fsync: bool = False,
        robot_view: bool = True,
    ) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.segment_chunks = segment_chunks
        self.fsync = fsync
        existing = sorted(self.dir.glob(SEGMENT_GLOB))
        self._next_index = int(existing[-1].stem.split("-")[1]) + 1 if existing else 0
        self._file: BinaryIO | None = None
        self._writer: ProtobufMcap | None = None
        self._count = 0
        self._good = 0
        """Bytes of the open segment up to the end of its last complete chunk."""
        self.path: Path | None = None
        self._robot = RobotView() if robot_view else None
        self._modelled: set[str] = set()
        """Collectors whose robot model this segment already holds."""

    def _open(self) -> None:
        self.path = self.dir / f"segment-{self._next_index:06d}.mcap"
        self._next_index += 1
        self._file = open(self.path, "wb")  # noqa: SIM115 - lives until rotation
        self._writer = ProtobufMcap(self._file)
        self._count = 0
        self._good = 0
        self._modelled = set()

    def write(self, chunk: pb.TransitionChunk) -> None:
        """Append one chunk and flush it. On an ``OSError`` (a full volume: ENOSPC, EDQUOT) the
        segment is cut back to its last complete chunk and closed, a segment that holds none is
        removed, and the error is raised again: what is on disk stays readable, and the next
        call starts a new segment."""
        try:
            self._write(chunk)
        except OSError:
            self._abandon()
            raise

    def _write(self, chunk: pb.TransitionChunk) -> None:
        if self._writer is None:
            self._open()
        assert self._writer is not None and self._file is not None
        stamp = int(chunk.header.stamp * 1e9)
        self._writer.write(
            topic_for(chunk.collector_id), chunk, stamp, sequence=int(chunk.seq) & 0xFFFFFFFF
        )
        if self._robot is not None:
            cid = chunk.collector_id
            try:
                for topic, t, msg in self._robot.messages(chunk, cid not in self._modelled):
                    self._writer.write(topic, msg, t)
                    self._modelled.add(cid)
            except Exception as e:  # the view is a by-product: never lose the chunk for it
                log.warning("robot view of chunk %s/%d skipped: %s", cid, chunk.seq, e)
        self._writer.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self._good = self._file.tell()
        self._count += 1
        if self._count >= self.segment_chunks:
            self.close()

    def _abandon(self) -> None:
        """Drop the open segment's partial tail after a failed write (see :meth:`write`)."""
        f, path, good = self._file, self.path, self._good
        self._writer, self._file = None, None
        if f is not None:
            try:
                f.close()  # flushes what the writer still buffers: may fail again
            except OSError:
                pass
        if path is None:
            return
        try:
            if good == 0:
                path.unlink(missing_ok=True)
            else:
                os.truncate(path, good)
        except OSError as e:
            log.error("could not cut %s back to its last complete chunk: %s", path.name, e)

    def close(self) -> None:
        if self._writer is not None and self._file is not None:
            self._writer.finish()
            self._file.close()
        self._writer, self._file = None, None


def read_segment(path: Path) -> Iterator[pb.TransitionChunk]:
    """Every complete ``TransitionChunk`` of one segment, finished or not."""
    channels: dict[int, Channel] = {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    ch = channels.get(record.channel_id)
                    if ch is None or not ch.topic.startswith(TRANSITIONS_PREFIX):
                        continue  # the robot's Foxglove view
                    msg = pb.TransitionChunk()
                    msg.ParseFromString(record.data)
                    yield msg
        except Exception as e:  # a segment cut by a crash ends in a partial record
            log.info(
                "segment %s ends early (%s): read up to its last complete record",
                path.name,
                type(e).__name__,
            )


def read_all(directory: Path) -> Iterator[pb.TransitionChunk]:
    """Every chunk of every segment, oldest segment first."""
    for path in sorted(Path(directory).glob(SEGMENT_GLOB)):
        yield from read_segment(path)
