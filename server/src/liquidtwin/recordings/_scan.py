"""MCAP container checks and raw message iteration, with every failure as a RecordingError.

Before any message is read, :func:`check_file` verifies the magic bytes at both ends, the
footer, the summary-section CRC and the data-section CRC (when the writer stored them), so
a truncated, unfinished or bit-flipped file is refused up front instead of yielding wrong data.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Iterator, NamedTuple

from mcap.reader import SeekingReader

from .base import RecordingError

MAGIC = b"\x89MCAP0\r\n"
_FOOTER = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc
_DATA_END = 1 + 8 + 4  # opcode, length, data_section_crc
_OP_FOOTER, _OP_DATA_END = 0x02, 0x0F
_BLOCK = 1 << 22


class RawMessage(NamedTuple):
    """One MCAP message, undecoded. ``log_time`` in ns; ``index`` counts messages in file order
    (log-time order when iterated that way)."""

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    log_time: int
    data: bytes
    index: int


def _crc(f, start: int, stop: int) -> int:
    f.seek(start)
    crc, left = 0, stop - start
    while left > 0:
        block = f.read(min(_BLOCK, left))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


def check_file(path: str | Path) -> Path:
    """Raise RecordingError unless ``path`` is a complete, undamaged MCAP file."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording file")
    size = path.stat().st_size
    if size == 0:
        raise RecordingError(f"{path}: the file is empty (0 bytes), not an MCAP recording")
    with open(path, "rb") as f:
        head = f.read(24)
        if head[:len(MAGIC)] != MAGIC[:len(head)]:
            raise RecordingError(f"{path}: not an MCAP file: it starts with {head!r}, "
                                 f"expected the MCAP magic {MAGIC!r}")
        if size < 2 * len(MAGIC) + _DATA_END + _FOOTER:
            raise RecordingError(f"{path}: truncated MCAP file ({size} bytes: too short to hold "
                                 "a header, data-end record and footer)")
        f.seek(size - len(MAGIC))
        if f.read(len(MAGIC)) != MAGIC:
            raise RecordingError(f"{path}: truncated or unfinished MCAP file: no footer magic at "
                                 f"the end of its {size} bytes (was the writer closed?)")
        footer_at = size - len(MAGIC) - _FOOTER
        f.seek(footer_at)
        op, length, summary_start, summary_offsets, summary_crc = struct.unpack(
            "<BQQQI", f.read(_FOOTER))
        if op != _OP_FOOTER or length != _FOOTER - 9:
            raise RecordingError(f"{path}: damaged MCAP file: no footer record before the end "
                                 f"magic (opcode {op:#x}, length {length})")
        if summary_start and not len(MAGIC) + _DATA_END <= summary_start <= footer_at \
                or summary_offsets and not summary_start <= summary_offsets <= footer_at:
            raise RecordingError(f"{path}: damaged MCAP file: footer points outside the file "
                                 f"(summary at {summary_start}, offsets at {summary_offsets})")
        if summary_crc:  # covers the summary section and the footer up to this CRC
            actual = _crc(f, summary_start or footer_at, size - len(MAGIC) - 4)
            if actual != summary_crc:
                raise RecordingError(f"{path}: damaged MCAP file: summary section CRC "
                                     f"{actual:#010x} != stored {summary_crc:#010x}")
        data_end_at = (summary_start or footer_at) - _DATA_END
        f.seek(data_end_at)
        op, length, data_crc = struct.unpack("<BQI", f.read(_DATA_END))
        if op != _OP_DATA_END or length != 4:
            raise RecordingError(f"{path}: damaged MCAP file: no data-end record at byte "
                                 f"{data_end_at} (opcode {op:#x})")
        if data_crc:
            actual = _crc(f, 0, data_end_at)
            if actual != data_crc:
                raise RecordingError(f"{path}: damaged MCAP file: data section CRC "
                                     f"{actual:#010x} != stored {data_crc:#010x}")
    return path


def iter_raw(path: Path, *, log_time_order: bool) -> Iterator[RawMessage]:
    """Messages of a file that passed :func:`check_file`, in file or log-time order (ties in
    file order). Errors of the MCAP library become RecordingError."""
    with open(path, "rb") as f:
        try:
            # no record is longer than the file: a damaged length fails fast, without a huge read
            reader = SeekingReader(f, validate_crcs=True,
                                   record_size_limit=max(path.stat().st_size, 1))
            it = reader.iter_messages(log_time_order=log_time_order)
        except Exception as e:
            raise _damaged(path, e) from e
        index = 0
        while True:
            try:
                schema, channel, message = next(it)
            except StopIteration:
                return
            except Exception as e:  # the mcap library raises many types on damaged input
                raise _damaged(path, e) from e
            yield RawMessage(
                channel.topic, schema.name if schema is not None else "",
                schema.encoding if schema is not None else "", channel.message_encoding,
                message.log_time, message.data, index)
            index += 1


def _damaged(path: Path, e: Exception) -> RecordingError:
    return RecordingError(f"{path}: damaged or truncated MCAP data ({type(e).__name__}: {e})")
