"""RESULTS.mcap: everything a session sent back, readable in Foxglove.

Layout (protobuf encoding, schemas embedded, zstd chunks):

- ``/out/<stream>`` for stream in particles, volumes, control, overlay, metrics — the
  output payloads exactly as received (foxglove.PointCloud, liquidtwin.v1.Volumes,
  liquidtwin.v1.Control, foxglove.RawImage, liquidtwin.v1.Metrics);
- ``/session`` — liquidtwin.v1.SessionStatus as the server reported it (after creation,
  at the end).

Every message's log time is the client's receive time and its publish time the answered
frame's stamp (``Header.stamp_ns``), both ns since the Unix epoch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from liquidtwin_proto import OUT_STREAMS, SessionStatus, now_ns
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.schema import register_schema

from .messages import STREAM_TYPES, Output

LIBRARY = "liquidtwin-client/1"
STATUS_TOPIC = "/session"


def out_topic(stream: str) -> str:
    """``/out/<stream>``."""
    return f"/out/{stream}"


class ResultsWriter:
    """Context manager writing a RESULTS.mcap (see the module docstring).

    Args:
        path: output file; parent directories are created, an existing file replaced.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._writer = Writer(self._file)
        self._writer.start(profile="", library=LIBRARY)
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def _channel(self, topic: str, cls) -> int:
        if topic not in self._channels:
            schema = register_schema(self._writer, cls)
            self._channels[topic] = self._writer.register_channel(topic, "protobuf", schema)
        return self._channels[topic]

    def write(self, out: Output) -> None:
        """Append one output (log time = receive time, publish time = frame stamp)."""
        topic = out_topic(out.stream)
        channel = self._channel(topic, STREAM_TYPES[out.stream])
        self._writer.add_message(channel, log_time=int(out.received_ns), data=out.payload,
                                 publish_time=int(out.header.stamp_ns), sequence=out.header.seq)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def write_status(self, status: SessionStatus, received_ns: int | None = None) -> None:
        """Append a SessionStatus on ``/session`` (log and publish time = receive time)."""
        t = now_ns() if received_ns is None else int(received_ns)
        channel = self._channel(STATUS_TOPIC, SessionStatus)
        self._writer.add_message(channel, log_time=t, data=status.SerializeToString(),
                                 publish_time=t)
        self.counts[STATUS_TOPIC] = self.counts.get(STATUS_TOPIC, 0) + 1

    def close(self) -> None:
        """Finish the file (summary, footer) and close it (idempotent)."""
        if self._file.closed:
            return
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> ResultsWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class ResultMessage:
    """One message read back: times in ns since the Unix epoch, the decoded protobuf."""

    log_time_ns: int
    publish_time_ns: int
    message: object


def read_results(path: str | Path) -> dict[str, list[ResultMessage]]:
    """A RESULTS.mcap by stream ("particles", …, and "session"), each in log-time order."""
    types = {out_topic(s): (s, STREAM_TYPES[s]) for s in OUT_STREAMS}
    types[STATUS_TOPIC] = ("session", SessionStatus)
    out: dict[str, list[ResultMessage]] = {}
    with Path(path).open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.topic not in types:
                continue
            stream, cls = types[channel.topic]
            if schema is None or schema.name != cls.DESCRIPTOR.full_name:
                raise ValueError(f"{path}: {channel.topic} has schema "
                                 f"{schema.name if schema else None!r}, expected "
                                 f"{cls.DESCRIPTOR.full_name}")
            out.setdefault(stream, []).append(ResultMessage(
                message.log_time, message.publish_time, cls.FromString(message.data)))
    return out
