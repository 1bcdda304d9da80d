"""Headers, attachments and errors as they cross Zenoh (see liquidtwin.proto, "Sessions").

Every stream sample carries its sender's serialized :class:`Header` as the Zenoh
attachment; every RPC request is a message whose first field is a Header; a failed RPC
is answered with ``reply_err`` carrying an :class:`Error`. These helpers build and check
those pieces the same way in the server, the client and the viewer.
"""

from __future__ import annotations

import time

from google.protobuf.message import DecodeError, Message

from .keys import validate_session_id
from .liquidtwin_pb2 import PROTOCOL_VERSION_CURRENT, Error, Header

#: Default limit on one Zenoh payload the server accepts, bytes (a 1280×960 mono8 mask is
#: 1.2 MB, a full-HD JPEG well under 1 MB).
DEFAULT_MAX_PAYLOAD = 16 * 1024 * 1024

#: Largest attachment (a serialized Header) accepted, bytes.
MAX_ATTACHMENT = 1024


class WireError(ValueError):
    """A message that cannot be accepted; ``code`` is the ``Error.Code`` to answer with."""

    def __init__(self, message: str, code: int = Error.BAD_REQUEST):
        super().__init__(message)
        self.code = code

    def to_error(self, header: Header | None = None) -> Error:
        """This failure as an ``Error`` message (the payload of a reply_err)."""
        err = Error(code=self.code, message=str(self))
        if header is not None:
            err.header.CopyFrom(header)
        return err


def now_ns() -> int:
    """Wall-clock time, nanoseconds since the Unix epoch."""
    return time.time_ns()


def make_header(session_id: str = "", seq: int = 0, stamp_ns: int | None = None) -> Header:
    """A Header speaking this package's protocol version (stamp defaults to now)."""
    return Header(session_id=session_id, seq=seq, version=PROTOCOL_VERSION_CURRENT,
                  stamp_ns=now_ns() if stamp_ns is None else stamp_ns)


def check_header(header: Header, session_id: str | None = None) -> Header:
    """Raise WireError unless ``header`` speaks our version (and names ``session_id``).

    An unset version (0) is refused too: every sender must say what it speaks.
    """
    if header.version != PROTOCOL_VERSION_CURRENT:
        raise WireError(
            f"unsupported protocol version {header.version} (this peer speaks "
            f"{PROTOCOL_VERSION_CURRENT}); upgrade the client or the server",
            Error.UNSUPPORTED_VERSION,
        )
    if session_id is not None and header.session_id and header.session_id != session_id:
        raise WireError(f"header names session {header.session_id!r} but the key names "
                        f"{session_id!r}")
    if header.session_id:
        try:
            validate_session_id(header.session_id)
        except ValueError as exc:
            raise WireError(str(exc)) from None
    return header


def parse(cls: type[Message], payload: bytes, *, max_bytes: int = DEFAULT_MAX_PAYLOAD,
          what: str | None = None) -> Message:
    """Decode ``payload`` as ``cls``; raise WireError (TOO_LARGE / BAD_REQUEST) on failure."""
    what = what or cls.DESCRIPTOR.full_name
    if len(payload) > max_bytes:
        raise WireError(f"{what} payload is {len(payload)} bytes; the limit is {max_bytes}",
                        Error.TOO_LARGE)
    msg = cls()
    try:
        msg.ParseFromString(bytes(payload))
    except (DecodeError, ValueError, RuntimeError) as exc:
        raise WireError(f"malformed {what}: {exc}") from None
    return msg


def parse_request(cls: type[Message], payload: bytes, *, max_bytes: int = DEFAULT_MAX_PAYLOAD,
                  session_id: str | None = None) -> Message:
    """Decode an RPC request whose field ``header`` must be present and check its version."""
    msg = parse(cls, payload, max_bytes=max_bytes)
    if not msg.HasField("header"):
        raise WireError(f"{cls.DESCRIPTOR.name} has no header; every request needs one "
                        f"(with version={PROTOCOL_VERSION_CURRENT})", Error.UNSUPPORTED_VERSION)
    check_header(msg.header, session_id)
    return msg


def encode_attachment(header: Header) -> bytes:
    """The attachment bytes of a stream sample."""
    return header.SerializeToString()


def decode_attachment(attachment: bytes | None, session_id: str | None = None) -> Header:
    """The checked Header of a stream sample; WireError when missing or bad."""
    if attachment is None:
        raise WireError("stream sample has no attachment; it must carry a serialized "
                        "liquidtwin Header", Error.UNSUPPORTED_VERSION)
    header = parse(Header, attachment, max_bytes=MAX_ATTACHMENT, what="Header attachment")
    return check_header(header, session_id)


def error_bytes(code: int, message: str, header: Header | None = None) -> bytes:
    """Serialized Error, the payload of a reply_err."""
    return WireError(message, code).to_error(header).SerializeToString()


def parse_error(payload: bytes) -> Error:
    """The Error of a reply_err payload (an INTERNAL error when it does not decode)."""
    err = Error()
    try:
        err.ParseFromString(bytes(payload))
    except (DecodeError, ValueError, RuntimeError):
        return Error(code=Error.INTERNAL, message=f"undecodable error reply ({len(payload)} bytes)")
    return err


def error_name(code: int) -> str:
    """``Error.Code`` name of ``code`` (e.g. "UNKNOWN_SESSION")."""
    try:
        return Error.Code.Name(code)
    except ValueError:
        return f"CODE_{code}"
