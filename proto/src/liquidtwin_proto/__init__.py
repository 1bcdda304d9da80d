"""liquidtwin's wire contract: generated protobuf messages, array codec, Zenoh keys.

Imports only numpy and protobuf, so the server, the robot-side client and the viewer
can all depend on it.
"""

from . import liquidtwin_pb2
from .codec import DEFAULT_MAX_BYTES, DTYPES, MAX_NDIM, ArrayError, pack_array, unpack_array
from .keys import (
    ALIVE_ROLES,
    ANY,
    DEFAULT_PREFIX,
    IN_STREAMS,
    MAX_ID_LENGTH,
    OUT_STREAMS,
    RESERVED_SESSION_IDS,
    Keys,
    ParsedKey,
    validate_id,
    validate_prefix,
    validate_session_id,
)
from .liquidtwin_pb2 import (
    ContainerVolume,
    Error,
    Fill,
    Header,
    PackedArray,
    ProtocolVersion,
    SceneObject,
    SceneSpec,
    SimulationSettings,
    Volumes,
)

#: Wire-contract version this package speaks; goes into ``Header.version``.
PROTOCOL_VERSION: int = liquidtwin_pb2.PROTOCOL_VERSION_CURRENT

__all__ = [
    "ALIVE_ROLES",
    "ANY",
    "ArrayError",
    "ContainerVolume",
    "DEFAULT_MAX_BYTES",
    "DEFAULT_PREFIX",
    "DTYPES",
    "Error",
    "Fill",
    "Header",
    "IN_STREAMS",
    "Keys",
    "MAX_ID_LENGTH",
    "MAX_NDIM",
    "OUT_STREAMS",
    "PROTOCOL_VERSION",
    "PackedArray",
    "ParsedKey",
    "ProtocolVersion",
    "RESERVED_SESSION_IDS",
    "SceneObject",
    "SceneSpec",
    "SimulationSettings",
    "Volumes",
    "liquidtwin_pb2",
    "pack_array",
    "unpack_array",
    "validate_id",
    "validate_prefix",
    "validate_session_id",
]
