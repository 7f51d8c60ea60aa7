"""The learner's replay on disk: MCAP segments of ``TransitionChunk`` protobuf messages.

Each segment is an MCAP file with the protobuf schema embedded, so Foxglove (or
``mcap cat``) opens it. Every message is written as its own compressed chunk and flushed at once,
so a learner killed with SIGKILL loses nothing it had written: on restart the unfinished tail
segment is read up to its last complete record and a new segment is started.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap_protobuf.writer import Writer

from proto import ursa_pb2 as pb

log = logging.getLogger(__name__)
SEGMENT_GLOB = "segment-*.mcap"


def topic_for(collector_id: str) -> str:
    """MCAP topic of one collector's chunks."""
    return f"/transitions/{collector_id}"


class ReplayWriter:
    """Appends chunks to the current segment; rotates after ``segment_chunks`` messages."""

    def __init__(self, directory: Path, segment_chunks: int = 2000, fsync: bool = False) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.segment_chunks = segment_chunks
        self.fsync = fsync
        existing = sorted(self.dir.glob(SEGMENT_GLOB))
        self._next_index = int(existing[-1].stem.split("-")[1]) + 1 if existing else 0
        self._file: BinaryIO | None = None
        self._writer: Writer | None = None
        self._count = 0
        self.path: Path | None = None

    def _open(self) -> None:
        self.path = self.dir / f"segment-{self._next_index:06d}.mcap"
        self._next_index += 1
        self._file = open(self.path, "wb")  # noqa: SIM115 - lives until rotation
        # chunk_size=1: every message closes its own chunk, so it is on disk after flush()
        self._writer = Writer(self._file, chunk_size=1)
        self._count = 0

    def write(self, chunk: pb.TransitionChunk) -> None:
        if self._writer is None:
            self._open()
        assert self._writer is not None and self._file is not None
        stamp = int(chunk.header.stamp * 1e9)
        self._writer.write_message(topic_for(chunk.collector_id), chunk, log_time=stamp,
                                   publish_time=stamp, sequence=int(chunk.seq) & 0xFFFFFFFF)
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self._count += 1
        if self._count >= self.segment_chunks:
            self.close()

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
                    msg = pb.TransitionChunk()
                    msg.ParseFromString(record.data)
                    yield msg
        except Exception as e:  # a segment cut by a crash ends in a partial record
            log.info("segment %s ends early (%s): read up to its last complete record",
                     path.name, type(e).__name__)


def read_all(directory: Path) -> Iterator[pb.TransitionChunk]:
    """Every chunk of every segment, oldest segment first."""
    for path in sorted(Path(directory).glob(SEGMENT_GLOB)):
        yield from read_segment(path)
