"""A session's MCAP log: every accepted input and every output, nothing lost on a kill.

Segments ``<session dir>/log-NNNN.mcap``; a server start opens the next number. Each segment
is unchunked and flushed after every message, so a killed server leaves a footerless file
whose records up to the kill all read back (:func:`read_log` reads records until the
truncation). Topics: ``/spec`` (the SessionSpec, first in every segment), ``/in/<stream>``
(the sample's payload as received; publish time = its header stamp, sequence = its header
seq) and ``/out/<stream>`` (as published; publish time = the frame stamp).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from ..recordings.writer import _descriptor_set

LIBRARY = "liquidtwin.service/1"
_SEGMENT = re.compile(r"log-(\d{4,})\.mcap")


def segments(directory) -> list[Path]:
    """The log segments of a session directory, oldest first."""
    d = Path(directory)
    found = [(int(m.group(1)), p) for p in d.glob("log-*.mcap") if (m := _SEGMENT.fullmatch(p.name))]
    return [p for _, p in sorted(found)]


class SessionLog:
    """Appends to a new segment of ``directory`` (thread-safe; call :meth:`close` at the end).

    Args:
      directory: the session's directory (created if missing).
      spec: the session's SessionSpec, written first as topic ``/spec``.
    """

    def __init__(self, directory, spec=None):
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        existing = segments(d)
        n = int(_SEGMENT.fullmatch(existing[-1].name).group(1)) + 1 if existing else 0
        self.path = d / f"log-{n:04d}.mcap"
        self._lock = threading.Lock()
        self._file = open(self.path, "xb")
        self._writer = Writer(self._file, use_chunking=False, compression=CompressionType.NONE)
        self._writer.start(profile="", library=LIBRARY)
        self._schemas: dict[type, int] = {}
        self._channels: dict[str, int] = {}
        self.messages = 0
        self._closed = False
        if spec is not None:
            self.write("/spec", spec, 0, 0)

    def write(self, topic: str, message, log_time_ns: int, publish_time_ns: int, sequence: int = 0,
              data: bytes | None = None) -> None:
        """Append one message and flush. ``message``: a protobuf message, or its class when
        ``data`` (the serialized bytes, e.g. an input sample as received) is given."""
        cls = message if isinstance(message, type) else type(message)
        payload = message.SerializeToString() if data is None else bytes(data)
        with self._lock:
            if self._closed:
                return
            if cls not in self._schemas:
                self._schemas[cls] = self._writer.register_schema(
                    name=cls.DESCRIPTOR.full_name, encoding=SchemaEncoding.Protobuf, data=_descriptor_set(cls))
            if topic not in self._channels:
                self._channels[topic] = self._writer.register_channel(
                    topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=self._schemas[cls])
            self._writer.add_message(self._channels[topic], log_time=max(0, int(log_time_ns)), data=payload,
                                     publish_time=max(0, int(publish_time_ns)), sequence=int(sequence) & 0xFFFFFFFF)
            self._file.flush()
            self.messages += 1

    def close(self) -> None:
        """Write the summary and footer (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
            finally:
                self._file.close()


@dataclass(frozen=True)
class LogRecord:
    """One logged message: topic, schema name, log/publish time ns, sequence, payload bytes."""

    topic: str
    schema: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes
    segment: str


def read_segment(path) -> Iterator[LogRecord]:
    """Records of one segment; stops quietly where a killed writer's file ends."""
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, record_size_limit=1 << 31)
        it = reader.records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except Exception:   # noqa: BLE001 - any decode failure here is the cut of a killed writer
                return          # truncated: everything before the cut has been yielded
            if isinstance(rec, Schema):
                schemas[rec.id] = rec.name
            elif isinstance(rec, Channel):
                channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
            elif isinstance(rec, Message) and rec.channel_id in channels:
                topic, schema = channels[rec.channel_id]
                yield LogRecord(topic, schema, rec.log_time, rec.publish_time, rec.sequence, bytes(rec.data),
                                Path(path).name)


def read_log(directory) -> Iterator[LogRecord]:
    """Every record of every segment of a session directory, in order."""
    for seg in segments(directory):
        yield from read_segment(seg)
