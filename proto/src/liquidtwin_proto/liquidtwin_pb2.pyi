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
