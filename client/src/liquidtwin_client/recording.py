"""What an MCAP recording holds: channels, message counts and time span."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader

MAGIC = b"\x89MCAP0\r\n"  # first and last 8 bytes of every complete MCAP file


class RecordingError(Exception):
    """A recording that is missing, unreadable or not a valid MCAP file."""


@dataclass(frozen=True)
class ChannelSummary:
    """One channel of a recording.

    Attributes:
        topic: channel topic, e.g. "/particles".
        schema_name: e.g. "foxglove.PointCloud"; "" for schemaless channels.
        schema_encoding: e.g. "protobuf"; "" for schemaless channels.
        message_encoding: e.g. "protobuf", "json".
        message_count: number of messages on the channel.
    """

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int


@dataclass(frozen=True)
class RecordingSummary:
    """A recording at a glance.

    Attributes:
        path: the file read.
        profile: MCAP header profile (often "" or "ros2").
        library: the writer library named in the MCAP header.
        channels: one entry per channel, sorted by topic.
        message_count: messages over all channels.
        start_ns: log time of the earliest message, ns since the Unix epoch; None if empty.
        end_ns: log time of the latest message, ns; None if empty.
        indexed: True if counts came from the file's statistics record, False if the
            messages were scanned because the file has none.
    """

    path: str
    profile: str
    library: str
    channels: tuple[ChannelSummary, ...]
    message_count: int
    start_ns: int | None
    end_ns: int | None
    indexed: bool

    @property
    def duration_s(self) -> float:
        """Span between the first and the last message, seconds (0 when empty)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * 1e-9


def summarize_recording(path: str | Path) -> RecordingSummary:
    """Read the channels, message counts and time span of an MCAP file.

    Uses the file's summary section (statistics) when present, else scans every message.

    Raises:
        RecordingError: the file is missing, unreadable, truncated or not an MCAP file.
    """
    path = Path(path)
    _check_file(path)
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream)
            header = reader.get_header()
            summary = reader.get_summary()
            if summary is not None and summary.statistics is not None:
                stats = summary.statistics
                counts = dict(stats.channel_message_counts)
                channels, schemas = summary.channels, summary.schemas
                total = stats.message_count
                span = (stats.message_start_time, stats.message_end_time) if total else None
                indexed = True
            else:
                channels, schemas, counts, total, span = _scan(reader)
                if summary is not None:  # keeps channels that carry no message
                    channels = {**channels, **summary.channels}
                    schemas = {**schemas, **summary.schemas}
                indexed = False
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc}") from exc
    except Exception as exc:  # the mcap library raises many kinds on corrupt input
        raise RecordingError(
            f"{path}: corrupt MCAP file ({type(exc).__name__}: {exc})"
        ) from exc

    rows = []
    for cid, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        rows.append(
            ChannelSummary(
                topic=channel.topic,
                schema_name=schema.name if schema else "",
                schema_encoding=schema.encoding if schema else "",
                message_encoding=channel.message_encoding,
                message_count=counts.get(cid, 0),
            )
        )
    rows.sort(key=lambda c: (c.topic, c.schema_name))
    return RecordingSummary(
        path=str(path),
        profile=header.profile,
        library=header.library,
        channels=tuple(rows),
        message_count=total,
        start_ns=span[0] if span else None,
        end_ns=span[1] if span else None,
        indexed=indexed,
    )


def _check_file(path: Path) -> None:
    """Raise RecordingError with a precise reason if ``path`` cannot be a complete MCAP."""
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    if not path.is_file():
        raise RecordingError(f"{path}: not a regular file")
    try:
        size = path.stat().st_size
        with path.open("rb") as stream:
            head = stream.read(len(MAGIC))
            stream.seek(max(0, size - len(MAGIC)))
            tail = stream.read(len(MAGIC))
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc}") from exc
    if size == 0:
        raise RecordingError(f"{path}: empty file, not an MCAP recording")
    if head != MAGIC:
        raise RecordingError(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
    if size < 2 * len(MAGIC) or tail != MAGIC:
        raise RecordingError(
            f"{path}: truncated MCAP file: it has no footer (was the recorder stopped "
            "before it finished the file?)"
        )


def _scan(reader):
    """Count messages by reading them all: (channels, schemas, counts, total, span)."""
    channels, schemas, counts = {}, {}, Counter()
    start = end = None
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        channels[channel.id] = channel
        if schema is not None:
            schemas[schema.id] = schema
        counts[channel.id] += 1
        t = message.log_time
        start = t if start is None else min(start, t)
        end = t if end is None else max(end, t)
    total = sum(counts.values())
    return channels, schemas, counts, total, (start, end) if total else None
