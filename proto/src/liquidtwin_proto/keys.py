"""Zenoh key expressions of liquidtwin (ARCHITECTURE.md, "Zenoh keys").

Under a configurable prefix (default ``liquidtwin``):

- ``<prefix>/<session>/in/{poses,camera,image,mask}``             streams into a session
- ``<prefix>/<session>/out/{particles,volumes,control,overlay,metrics}``  streams out
- ``<prefix>/rpc/<method>`` and ``<prefix>/<session>/rpc/<method>``  request/reply
- ``<prefix>/alive/{servers,clients}/<id>``                       liveliness tokens

Every id that becomes a key chunk (session, method, node id, prefix chunk) is 1 to
``MAX_ID_LENGTH`` characters from ``[A-Za-z0-9._-]``, so it can never smuggle in a
separator (``/``), a wildcard (``*``) or Zenoh's DSL marker (``$``). Session ids ``rpc``
and ``alive`` are reserved: they would collide with the global keys. Builders accept
``ANY`` (``*``) in place of any chunk to form subscription patterns.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

DEFAULT_PREFIX = "liquidtwin"
IN_STREAMS = ("poses", "camera", "image", "mask")
OUT_STREAMS = ("particles", "volumes", "control", "overlay", "metrics")
ALIVE_ROLES = ("servers", "clients")
MAX_ID_LENGTH = 64
RESERVED_SESSION_IDS = frozenset({"rpc", "alive"})

#: Stands for any single chunk in a subscription pattern.
ANY = "*"

_ID = re.compile(r"[A-Za-z0-9._-]+")
_WHY = {
    "/": "'/' separates key chunks",
    "*": "'*' is a Zenoh wildcard",
    "$": "'$' starts Zenoh's key-expression DSL",
    "?": "'?' starts Zenoh selector parameters",
    "#": "'#' is reserved by Zenoh",
}


def validate_id(value: str, what: str = "id") -> str:
    """Return ``value`` if it is a valid single key chunk, else raise ValueError.

    Args:
        value: candidate chunk (session id, method name, node id).
        what: how to name it in the error message, e.g. "session id".
    """
    if not isinstance(value, str):
        raise TypeError(f"{what} must be a str, got {type(value).__name__}")
    if not value:
        raise ValueError(f"{what} must not be empty")
    if len(value) > MAX_ID_LENGTH:
        raise ValueError(
            f"{what} is {len(value)} characters long; at most {MAX_ID_LENGTH} allowed"
        )
    if not _ID.fullmatch(value):
        bad = next(c for c in value if not _ID.fullmatch(c))
        why = _WHY.get(bad, "only letters, digits, '.', '_' and '-' are allowed")
        raise ValueError(f"{what} {value!r} contains {bad!r}: {why}")
    return value


def validate_session_id(session: str) -> str:
    """Return ``session`` if it is a valid, unreserved session id, else raise ValueError."""
    validate_id(session, "session id")
    if session in RESERVED_SESSION_IDS:
        raise ValueError(f"session id {session!r} is reserved (it collides with global keys)")
    return session


def validate_prefix(prefix: str) -> str:
    """Return ``prefix`` if it is one or more valid chunks joined by '/', else raise."""
    if not isinstance(prefix, str) or not prefix:
        raise ValueError("key prefix must be a non-empty string")
    for chunk in prefix.split("/"):
        if not chunk:
            raise ValueError(
                f"key prefix {prefix!r} has an empty chunk (leading, trailing or '//')"
            )
        validate_id(chunk, f"key prefix {prefix!r} chunk")
    return prefix


@dataclass(frozen=True)
class ParsedKey:
    """A liquidtwin key taken apart.

    Attributes:
        kind: "in", "out", "rpc" or "alive".
        name: the stream (in/out), method (rpc) or node id (alive).
        session: the session id; None for global rpc keys and liveliness keys.
        role: "servers" or "clients" for liveliness keys, else None.
    """

    kind: str
    name: str
    session: str | None = None
    role: str | None = None


@dataclass(frozen=True)
class Keys:
    """Builds and parses liquidtwin's key expressions under one prefix.

    >>> Keys().stream_in("robot-1", "poses")
    'liquidtwin/robot-1/in/poses'
    >>> Keys("lab/liquidtwin").rpc("status")
    'lab/liquidtwin/rpc/status'
    >>> Keys().stream_in(ANY, ANY)
    'liquidtwin/*/in/*'
    """

    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        validate_prefix(self.prefix)

    def stream_in(self, session: str, stream: str) -> str:
        """Key of input ``stream`` (one of IN_STREAMS) of ``session``."""
        return self._join(_session(session), "in", _member(stream, IN_STREAMS, "input stream"))

    def stream_out(self, session: str, stream: str) -> str:
        """Key of output ``stream`` (one of OUT_STREAMS) of ``session``."""
        return self._join(
            _session(session), "out", _member(stream, OUT_STREAMS, "output stream")
        )

    def rpc(self, method: str, session: str | None = None) -> str:
        """Key of RPC ``method``: global when ``session`` is None, else per session."""
        method = _chunk(method, "rpc method")
        if session is None:
            return self._join("rpc", method)
        return self._join(_session(session), "rpc", method)

    def alive(self, role: str, node_id: str) -> str:
        """Liveliness key of a node; ``role`` is "servers" or "clients"."""
        return self._join(
            "alive", _member(role, ALIVE_ROLES, "liveliness role"), _chunk(node_id, "node id")
        )

    def parse(self, key: str) -> ParsedKey:
        """Take a concrete key (no wildcards) apart; raise ValueError if it is not ours."""
        head = self.prefix + "/"
        if not isinstance(key, str) or not key.startswith(head):
            raise ValueError(f"key {key!r} is not under prefix {self.prefix!r}")
        parts = key[len(head) :].split("/")
        if len(parts) == 2 and parts[0] == "rpc":
            return ParsedKey("rpc", validate_id(parts[1], "rpc method"))
        if len(parts) == 3 and parts[0] == "alive":
            role = parts[1]
            if role not in ALIVE_ROLES:
                raise ValueError(f"key {key!r}: liveliness role {role!r} not in {ALIVE_ROLES}")
            return ParsedKey("alive", validate_id(parts[2], "node id"), role=role)
        if len(parts) == 3 and parts[1] in ("in", "out", "rpc"):
            session, kind, name = parts
            validate_session_id(session)
            if kind == "in" and name not in IN_STREAMS:
                raise ValueError(f"key {key!r}: unknown input stream {name!r}")
            if kind == "out" and name not in OUT_STREAMS:
                raise ValueError(f"key {key!r}: unknown output stream {name!r}")
            if kind == "rpc":
                validate_id(name, "rpc method")
            return ParsedKey(kind, name, session=session)
        raise ValueError(f"key {key!r} does not match any liquidtwin key layout")

    def _join(self, *chunks: str) -> str:
        return "/".join((self.prefix, *chunks))


def _chunk(value: str, what: str) -> str:
    return value if value == ANY else validate_id(value, what)


def _session(session: str) -> str:
    return session if session == ANY else validate_session_id(session)


def _member(value: str, allowed: tuple[str, ...], what: str) -> str:
    if value != ANY and value not in allowed:
        raise ValueError(f"unknown {what} {value!r}; expected one of {', '.join(allowed)}")
    return value
