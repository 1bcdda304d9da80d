from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class ProtocolVersion(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    PROTOCOL_VERSION_UNSPECIFIED: _ClassVar[ProtocolVersion]
    PROTOCOL_VERSION_1: _ClassVar[ProtocolVersion]
    PROTOCOL_VERSION_CURRENT: _ClassVar[ProtocolVersion]
PROTOCOL_VERSION_UNSPECIFIED: ProtocolVersion
PROTOCOL_VERSION_1: ProtocolVersion
PROTOCOL_VERSION_CURRENT: ProtocolVersion

class Header(_message.Message):
    __slots__ = ("session_id", "seq", "stamp_ns", "version")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    seq: int
    stamp_ns: int
    version: int
    def __init__(self, session_id: _Optional[str] = ..., seq: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., version: _Optional[int] = ...) -> None: ...

class PackedArray(_message.Message):
    __slots__ = ("shape", "dtype", "data")
    SHAPE_FIELD_NUMBER: _ClassVar[int]
    DTYPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    shape: _containers.RepeatedScalarFieldContainer[int]
    dtype: str
    data: bytes
    def __init__(self, shape: _Optional[_Iterable[int]] = ..., dtype: _Optional[str] = ..., data: _Optional[bytes] = ...) -> None: ...

class Error(_message.Message):
    __slots__ = ("header", "code", "message")
    class Code(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        CODE_UNSPECIFIED: _ClassVar[Error.Code]
        BAD_REQUEST: _ClassVar[Error.Code]
        UNKNOWN_SESSION: _ClassVar[Error.Code]
        UNSUPPORTED_VERSION: _ClassVar[Error.Code]
        TOO_LARGE: _ClassVar[Error.Code]
        NON_FINITE: _ClassVar[Error.Code]
        INTERNAL: _ClassVar[Error.Code]
    CODE_UNSPECIFIED: Error.Code
    BAD_REQUEST: Error.Code
    UNKNOWN_SESSION: Error.Code
    UNSUPPORTED_VERSION: Error.Code
    TOO_LARGE: Error.Code
    NON_FINITE: Error.Code
    INTERNAL: Error.Code
    HEADER_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    header: Header
    code: Error.Code
    message: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., code: _Optional[_Union[Error.Code, str]] = ..., message: _Optional[str] = ...) -> None: ...

class ContainerVolume(_message.Message):
    __slots__ = ("name", "ml")
    NAME_FIELD_NUMBER: _ClassVar[int]
    ML_FIELD_NUMBER: _ClassVar[int]
    name: str
    ml: float
    def __init__(self, name: _Optional[str] = ..., ml: _Optional[float] = ...) -> None: ...

class Volumes(_message.Message):
    __slots__ = ("header", "containers")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    CONTAINERS_FIELD_NUMBER: _ClassVar[int]
    header: Header
    containers: _containers.RepeatedCompositeFieldContainer[ContainerVolume]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., containers: _Optional[_Iterable[_Union[ContainerVolume, _Mapping]]] = ...) -> None: ...

class SceneObject(_message.Message):
    __slots__ = ("name", "model", "params", "mesh_uri", "mesh_sha256", "initial_pose", "container")
    class ParamsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    NAME_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    PARAMS_FIELD_NUMBER: _ClassVar[int]
    MESH_URI_FIELD_NUMBER: _ClassVar[int]
    MESH_SHA256_FIELD_NUMBER: _ClassVar[int]
    INITIAL_POSE_FIELD_NUMBER: _ClassVar[int]
    CONTAINER_FIELD_NUMBER: _ClassVar[int]
    name: str
    model: str
    params: _containers.ScalarMap[str, float]
    mesh_uri: str
    mesh_sha256: str
    initial_pose: _containers.RepeatedScalarFieldContainer[float]
    container: bool
    def __init__(self, name: _Optional[str] = ..., model: _Optional[str] = ..., params: _Optional[_Mapping[str, float]] = ..., mesh_uri: _Optional[str] = ..., mesh_sha256: _Optional[str] = ..., initial_pose: _Optional[_Iterable[float]] = ..., container: _Optional[bool] = ...) -> None: ...

class Fill(_message.Message):
    __slots__ = ("container", "volume_ml", "fraction")
    CONTAINER_FIELD_NUMBER: _ClassVar[int]
    VOLUME_ML_FIELD_NUMBER: _ClassVar[int]
    FRACTION_FIELD_NUMBER: _ClassVar[int]
    container: str
    volume_ml: float
    fraction: float
    def __init__(self, container: _Optional[str] = ..., volume_ml: _Optional[float] = ..., fraction: _Optional[float] = ...) -> None: ...

class SimulationSettings(_message.Message):
    __slots__ = ("h", "dt", "iterations", "spacing")
    H_FIELD_NUMBER: _ClassVar[int]
    DT_FIELD_NUMBER: _ClassVar[int]
    ITERATIONS_FIELD_NUMBER: _ClassVar[int]
    SPACING_FIELD_NUMBER: _ClassVar[int]
    h: float
    dt: float
    iterations: int
    spacing: float
    def __init__(self, h: _Optional[float] = ..., dt: _Optional[float] = ..., iterations: _Optional[int] = ..., spacing: _Optional[float] = ...) -> None: ...

class SceneSpec(_message.Message):
    __slots__ = ("header", "name", "objects", "fills", "simulation", "motion", "motion_params", "duration_s", "cameras")
    class MotionParamsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    FILLS_FIELD_NUMBER: _ClassVar[int]
    SIMULATION_FIELD_NUMBER: _ClassVar[int]
    MOTION_FIELD_NUMBER: _ClassVar[int]
    MOTION_PARAMS_FIELD_NUMBER: _ClassVar[int]
    DURATION_S_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    header: Header
    name: str
    objects: _containers.RepeatedCompositeFieldContainer[SceneObject]
    fills: _containers.RepeatedCompositeFieldContainer[Fill]
    simulation: SimulationSettings
    motion: str
    motion_params: _containers.ScalarMap[str, float]
    duration_s: float
    cameras: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., name: _Optional[str] = ..., objects: _Optional[_Iterable[_Union[SceneObject, _Mapping]]] = ..., fills: _Optional[_Iterable[_Union[Fill, _Mapping]]] = ..., simulation: _Optional[_Union[SimulationSettings, _Mapping]] = ..., motion: _Optional[str] = ..., motion_params: _Optional[_Mapping[str, float]] = ..., duration_s: _Optional[float] = ..., cameras: _Optional[_Iterable[str]] = ...) -> None: ...
