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

class TrackingMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TRACKING_MODE_UNSPECIFIED: _ClassVar[TrackingMode]
    OPEN_LOOP: _ClassVar[TrackingMode]
    WARP_FIELD: _ClassVar[TrackingMode]
    MAP_FILTER: _ClassVar[TrackingMode]
    SPNETS_PERCEPTION: _ClassVar[TrackingMode]
PROTOCOL_VERSION_UNSPECIFIED: ProtocolVersion
PROTOCOL_VERSION_1: ProtocolVersion
PROTOCOL_VERSION_CURRENT: ProtocolVersion
TRACKING_MODE_UNSPECIFIED: TrackingMode
OPEN_LOOP: TrackingMode
WARP_FIELD: TrackingMode
MAP_FILTER: TrackingMode
SPNETS_PERCEPTION: TrackingMode

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
        ALREADY_EXISTS: _ClassVar[Error.Code]
        UNKNOWN_NAME: _ClassVar[Error.Code]
        RESOURCE_EXHAUSTED: _ClassVar[Error.Code]
        INFEASIBLE: _ClassVar[Error.Code]
    CODE_UNSPECIFIED: Error.Code
    BAD_REQUEST: Error.Code
    UNKNOWN_SESSION: Error.Code
    UNSUPPORTED_VERSION: Error.Code
    TOO_LARGE: Error.Code
    NON_FINITE: Error.Code
    INTERNAL: Error.Code
    ALREADY_EXISTS: Error.Code
    UNKNOWN_NAME: Error.Code
    RESOURCE_EXHAUSTED: Error.Code
    INFEASIBLE: Error.Code
    HEADER_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    header: Header
    code: Error.Code
    message: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., code: _Optional[_Union[Error.Code, str]] = ..., message: _Optional[str] = ...) -> None: ...

class ContainerVolume(_message.Message):
    __slots__ = ("name", "ml", "mask_ml")
    NAME_FIELD_NUMBER: _ClassVar[int]
    ML_FIELD_NUMBER: _ClassVar[int]
    MASK_ML_FIELD_NUMBER: _ClassVar[int]
    name: str
    ml: float
    mask_ml: float
    def __init__(self, name: _Optional[str] = ..., ml: _Optional[float] = ..., mask_ml: _Optional[float] = ...) -> None: ...

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
    __slots__ = ("h", "dt", "iterations", "spacing", "reference_iterations", "max_correction_spacings", "cut_wall_pairs")
    H_FIELD_NUMBER: _ClassVar[int]
    DT_FIELD_NUMBER: _ClassVar[int]
    ITERATIONS_FIELD_NUMBER: _ClassVar[int]
    SPACING_FIELD_NUMBER: _ClassVar[int]
    REFERENCE_ITERATIONS_FIELD_NUMBER: _ClassVar[int]
    MAX_CORRECTION_SPACINGS_FIELD_NUMBER: _ClassVar[int]
    CUT_WALL_PAIRS_FIELD_NUMBER: _ClassVar[int]
    h: float
    dt: float
    iterations: int
    spacing: float
    reference_iterations: int
    max_correction_spacings: float
    cut_wall_pairs: bool
    def __init__(self, h: _Optional[float] = ..., dt: _Optional[float] = ..., iterations: _Optional[int] = ..., spacing: _Optional[float] = ..., reference_iterations: _Optional[int] = ..., max_correction_spacings: _Optional[float] = ..., cut_wall_pairs: _Optional[bool] = ...) -> None: ...

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

class FluidParameters(_message.Message):
    __slots__ = ("lambda_c", "lambda_v", "lambda_s", "lambda_omega", "relaxation")
    LAMBDA_C_FIELD_NUMBER: _ClassVar[int]
    LAMBDA_V_FIELD_NUMBER: _ClassVar[int]
    LAMBDA_S_FIELD_NUMBER: _ClassVar[int]
    LAMBDA_OMEGA_FIELD_NUMBER: _ClassVar[int]
    RELAXATION_FIELD_NUMBER: _ClassVar[int]
    lambda_c: float
    lambda_v: float
    lambda_s: float
    lambda_omega: float
    relaxation: float
    def __init__(self, lambda_c: _Optional[float] = ..., lambda_v: _Optional[float] = ..., lambda_s: _Optional[float] = ..., lambda_omega: _Optional[float] = ..., relaxation: _Optional[float] = ...) -> None: ...

class CameraSetup(_message.Message):
    __slots__ = ("name", "width", "height", "k", "d", "pose")
    NAME_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    K_FIELD_NUMBER: _ClassVar[int]
    D_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    name: str
    width: int
    height: int
    k: _containers.RepeatedScalarFieldContainer[float]
    d: _containers.RepeatedScalarFieldContainer[float]
    pose: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, name: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., k: _Optional[_Iterable[float]] = ..., d: _Optional[_Iterable[float]] = ..., pose: _Optional[_Iterable[float]] = ...) -> None: ...

class SessionSpec(_message.Message):
    __slots__ = ("scene", "cameras", "fluid", "tracking", "device", "correction_gain", "mask_source", "pose_filter")
    SCENE_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    FLUID_FIELD_NUMBER: _ClassVar[int]
    TRACKING_FIELD_NUMBER: _ClassVar[int]
    DEVICE_FIELD_NUMBER: _ClassVar[int]
    CORRECTION_GAIN_FIELD_NUMBER: _ClassVar[int]
    MASK_SOURCE_FIELD_NUMBER: _ClassVar[int]
    POSE_FILTER_FIELD_NUMBER: _ClassVar[int]
    scene: SceneSpec
    cameras: _containers.RepeatedCompositeFieldContainer[CameraSetup]
    fluid: FluidParameters
    tracking: TrackingMode
    device: str
    correction_gain: float
    mask_source: str
    pose_filter: PoseFilter
    def __init__(self, scene: _Optional[_Union[SceneSpec, _Mapping]] = ..., cameras: _Optional[_Iterable[_Union[CameraSetup, _Mapping]]] = ..., fluid: _Optional[_Union[FluidParameters, _Mapping]] = ..., tracking: _Optional[_Union[TrackingMode, str]] = ..., device: _Optional[str] = ..., correction_gain: _Optional[float] = ..., mask_source: _Optional[str] = ..., pose_filter: _Optional[_Union[PoseFilter, _Mapping]] = ...) -> None: ...

class PoseFilter(_message.Message):
    __slots__ = ("position_noise_m", "rotation_noise_rad", "acceleration_m_s2", "angular_acceleration_rad_s2")
    POSITION_NOISE_M_FIELD_NUMBER: _ClassVar[int]
    ROTATION_NOISE_RAD_FIELD_NUMBER: _ClassVar[int]
    ACCELERATION_M_S2_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_ACCELERATION_RAD_S2_FIELD_NUMBER: _ClassVar[int]
    position_noise_m: float
    rotation_noise_rad: float
    acceleration_m_s2: float
    angular_acceleration_rad_s2: float
    def __init__(self, position_noise_m: _Optional[float] = ..., rotation_noise_rad: _Optional[float] = ..., acceleration_m_s2: _Optional[float] = ..., angular_acceleration_rad_s2: _Optional[float] = ...) -> None: ...

class Task(_message.Message):
    __slots__ = ("pour", "catch_stream", "send", "controller")
    class PourToVolume(_message.Message):
        __slots__ = ("source", "target", "volume_ml", "max_angle_rad", "max_rate_rad_s", "top_up")
        SOURCE_FIELD_NUMBER: _ClassVar[int]
        TARGET_FIELD_NUMBER: _ClassVar[int]
        VOLUME_ML_FIELD_NUMBER: _ClassVar[int]
        MAX_ANGLE_RAD_FIELD_NUMBER: _ClassVar[int]
        MAX_RATE_RAD_S_FIELD_NUMBER: _ClassVar[int]
        TOP_UP_FIELD_NUMBER: _ClassVar[int]
        source: str
        target: str
        volume_ml: float
        max_angle_rad: float
        max_rate_rad_s: float
        top_up: bool
        def __init__(self, source: _Optional[str] = ..., target: _Optional[str] = ..., volume_ml: _Optional[float] = ..., max_angle_rad: _Optional[float] = ..., max_rate_rad_s: _Optional[float] = ..., top_up: _Optional[bool] = ...) -> None: ...
    class CatchStream(_message.Message):
        __slots__ = ("source", "catcher", "max_speed_m_s", "range_m")
        SOURCE_FIELD_NUMBER: _ClassVar[int]
        CATCHER_FIELD_NUMBER: _ClassVar[int]
        MAX_SPEED_M_S_FIELD_NUMBER: _ClassVar[int]
        RANGE_M_FIELD_NUMBER: _ClassVar[int]
        source: str
        catcher: str
        max_speed_m_s: float
        range_m: float
        def __init__(self, source: _Optional[str] = ..., catcher: _Optional[str] = ..., max_speed_m_s: _Optional[float] = ..., range_m: _Optional[float] = ...) -> None: ...
    class SendToContainer(_message.Message):
        __slots__ = ("object", "target", "max_angle_rad", "max_rate_rad_s")
        OBJECT_FIELD_NUMBER: _ClassVar[int]
        TARGET_FIELD_NUMBER: _ClassVar[int]
        MAX_ANGLE_RAD_FIELD_NUMBER: _ClassVar[int]
        MAX_RATE_RAD_S_FIELD_NUMBER: _ClassVar[int]
        object: str
        target: str
        max_angle_rad: float
        max_rate_rad_s: float
        def __init__(self, object: _Optional[str] = ..., target: _Optional[str] = ..., max_angle_rad: _Optional[float] = ..., max_rate_rad_s: _Optional[float] = ...) -> None: ...
    POUR_FIELD_NUMBER: _ClassVar[int]
    CATCH_STREAM_FIELD_NUMBER: _ClassVar[int]
    SEND_FIELD_NUMBER: _ClassVar[int]
    CONTROLLER_FIELD_NUMBER: _ClassVar[int]
    pour: Task.PourToVolume
    catch_stream: Task.CatchStream
    send: Task.SendToContainer
    controller: str
    def __init__(self, pour: _Optional[_Union[Task.PourToVolume, _Mapping]] = ..., catch_stream: _Optional[_Union[Task.CatchStream, _Mapping]] = ..., send: _Optional[_Union[Task.SendToContainer, _Mapping]] = ..., controller: _Optional[str] = ...) -> None: ...

class Control(_message.Message):
    __slots__ = ("header", "object", "tilt_angle_rad", "tilt_rate_rad_s", "achieved_ml", "remaining_ml", "done", "controller", "axis_point_m", "axis_direction", "pose", "linear_velocity_m_s", "angular_velocity_rad_s")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    TILT_ANGLE_RAD_FIELD_NUMBER: _ClassVar[int]
    TILT_RATE_RAD_S_FIELD_NUMBER: _ClassVar[int]
    ACHIEVED_ML_FIELD_NUMBER: _ClassVar[int]
    REMAINING_ML_FIELD_NUMBER: _ClassVar[int]
    DONE_FIELD_NUMBER: _ClassVar[int]
    CONTROLLER_FIELD_NUMBER: _ClassVar[int]
    AXIS_POINT_M_FIELD_NUMBER: _ClassVar[int]
    AXIS_DIRECTION_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    LINEAR_VELOCITY_M_S_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_VELOCITY_RAD_S_FIELD_NUMBER: _ClassVar[int]
    header: Header
    object: str
    tilt_angle_rad: float
    tilt_rate_rad_s: float
    achieved_ml: float
    remaining_ml: float
    done: bool
    controller: str
    axis_point_m: _containers.RepeatedScalarFieldContainer[float]
    axis_direction: _containers.RepeatedScalarFieldContainer[float]
    pose: _containers.RepeatedScalarFieldContainer[float]
    linear_velocity_m_s: _containers.RepeatedScalarFieldContainer[float]
    angular_velocity_rad_s: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., object: _Optional[str] = ..., tilt_angle_rad: _Optional[float] = ..., tilt_rate_rad_s: _Optional[float] = ..., achieved_ml: _Optional[float] = ..., remaining_ml: _Optional[float] = ..., done: _Optional[bool] = ..., controller: _Optional[str] = ..., axis_point_m: _Optional[_Iterable[float]] = ..., axis_direction: _Optional[_Iterable[float]] = ..., pose: _Optional[_Iterable[float]] = ..., linear_velocity_m_s: _Optional[_Iterable[float]] = ..., angular_velocity_rad_s: _Optional[_Iterable[float]] = ...) -> None: ...

class OverlayInfo(_message.Message):
    __slots__ = ("camera", "observed_only_rgb", "model_only_rgb", "overlap_rgb", "observed_px", "model_px", "overlap_px")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_ONLY_RGB_FIELD_NUMBER: _ClassVar[int]
    MODEL_ONLY_RGB_FIELD_NUMBER: _ClassVar[int]
    OVERLAP_RGB_FIELD_NUMBER: _ClassVar[int]
    OBSERVED_PX_FIELD_NUMBER: _ClassVar[int]
    MODEL_PX_FIELD_NUMBER: _ClassVar[int]
    OVERLAP_PX_FIELD_NUMBER: _ClassVar[int]
    camera: str
    observed_only_rgb: int
    model_only_rgb: int
    overlap_rgb: int
    observed_px: int
    model_px: int
    overlap_px: int
    def __init__(self, camera: _Optional[str] = ..., observed_only_rgb: _Optional[int] = ..., model_only_rgb: _Optional[int] = ..., overlap_rgb: _Optional[int] = ..., observed_px: _Optional[int] = ..., model_px: _Optional[int] = ..., overlap_px: _Optional[int] = ...) -> None: ...

class Metrics(_message.Message):
    __slots__ = ("header", "input_seq", "sim_time_s", "iou", "step_ms", "correction_ms", "lag_ms", "sim_lag_s", "particles", "steps", "frames_in", "frames_done", "dropped_stale", "dropped_out_of_order", "rejected", "overlay")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    INPUT_SEQ_FIELD_NUMBER: _ClassVar[int]
    SIM_TIME_S_FIELD_NUMBER: _ClassVar[int]
    IOU_FIELD_NUMBER: _ClassVar[int]
    STEP_MS_FIELD_NUMBER: _ClassVar[int]
    CORRECTION_MS_FIELD_NUMBER: _ClassVar[int]
    LAG_MS_FIELD_NUMBER: _ClassVar[int]
    SIM_LAG_S_FIELD_NUMBER: _ClassVar[int]
    PARTICLES_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_IN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DONE_FIELD_NUMBER: _ClassVar[int]
    DROPPED_STALE_FIELD_NUMBER: _ClassVar[int]
    DROPPED_OUT_OF_ORDER_FIELD_NUMBER: _ClassVar[int]
    REJECTED_FIELD_NUMBER: _ClassVar[int]
    OVERLAY_FIELD_NUMBER: _ClassVar[int]
    header: Header
    input_seq: int
    sim_time_s: float
    iou: float
    step_ms: float
    correction_ms: float
    lag_ms: float
    sim_lag_s: float
    particles: int
    steps: int
    frames_in: int
    frames_done: int
    dropped_stale: int
    dropped_out_of_order: int
    rejected: int
    overlay: OverlayInfo
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., input_seq: _Optional[int] = ..., sim_time_s: _Optional[float] = ..., iou: _Optional[float] = ..., step_ms: _Optional[float] = ..., correction_ms: _Optional[float] = ..., lag_ms: _Optional[float] = ..., sim_lag_s: _Optional[float] = ..., particles: _Optional[int] = ..., steps: _Optional[int] = ..., frames_in: _Optional[int] = ..., frames_done: _Optional[int] = ..., dropped_stale: _Optional[int] = ..., dropped_out_of_order: _Optional[int] = ..., rejected: _Optional[int] = ..., overlay: _Optional[_Union[OverlayInfo, _Mapping]] = ...) -> None: ...

class SessionStatus(_message.Message):
    __slots__ = ("header", "session_id", "state", "spec", "sim_time_s", "frames_done", "particles", "volumes", "task", "log_path", "checkpoint_path", "restored", "server_id", "model_json")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    SPEC_FIELD_NUMBER: _ClassVar[int]
    SIM_TIME_S_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DONE_FIELD_NUMBER: _ClassVar[int]
    PARTICLES_FIELD_NUMBER: _ClassVar[int]
    VOLUMES_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    LOG_PATH_FIELD_NUMBER: _ClassVar[int]
    CHECKPOINT_PATH_FIELD_NUMBER: _ClassVar[int]
    RESTORED_FIELD_NUMBER: _ClassVar[int]
    SERVER_ID_FIELD_NUMBER: _ClassVar[int]
    MODEL_JSON_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    state: str
    spec: SessionSpec
    sim_time_s: float
    frames_done: int
    particles: int
    volumes: _containers.RepeatedCompositeFieldContainer[ContainerVolume]
    task: Task
    log_path: str
    checkpoint_path: str
    restored: bool
    server_id: str
    model_json: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., state: _Optional[str] = ..., spec: _Optional[_Union[SessionSpec, _Mapping]] = ..., sim_time_s: _Optional[float] = ..., frames_done: _Optional[int] = ..., particles: _Optional[int] = ..., volumes: _Optional[_Iterable[_Union[ContainerVolume, _Mapping]]] = ..., task: _Optional[_Union[Task, _Mapping]] = ..., log_path: _Optional[str] = ..., checkpoint_path: _Optional[str] = ..., restored: _Optional[bool] = ..., server_id: _Optional[str] = ..., model_json: _Optional[str] = ...) -> None: ...

class CreateSessionRequest(_message.Message):
    __slots__ = ("header", "session_id", "spec", "client_id")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    SPEC_FIELD_NUMBER: _ClassVar[int]
    CLIENT_ID_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    spec: SessionSpec
    client_id: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., spec: _Optional[_Union[SessionSpec, _Mapping]] = ..., client_id: _Optional[str] = ...) -> None: ...

class ListSessionsRequest(_message.Message):
    __slots__ = ("header",)
    HEADER_FIELD_NUMBER: _ClassVar[int]
    header: Header
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ...) -> None: ...

class ListSessionsReply(_message.Message):
    __slots__ = ("header", "server_id", "sessions")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SERVER_ID_FIELD_NUMBER: _ClassVar[int]
    SESSIONS_FIELD_NUMBER: _ClassVar[int]
    header: Header
    server_id: str
    sessions: _containers.RepeatedCompositeFieldContainer[SessionStatus]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., server_id: _Optional[str] = ..., sessions: _Optional[_Iterable[_Union[SessionStatus, _Mapping]]] = ...) -> None: ...

class SessionRequest(_message.Message):
    __slots__ = ("header",)
    HEADER_FIELD_NUMBER: _ClassVar[int]
    header: Header
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ...) -> None: ...

class SetTaskRequest(_message.Message):
    __slots__ = ("header", "task")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    header: Header
    task: Task
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., task: _Optional[_Union[Task, _Mapping]] = ...) -> None: ...

class ObjectMesh(_message.Message):
    __slots__ = ("name", "vertices", "faces", "container")
    NAME_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    FACES_FIELD_NUMBER: _ClassVar[int]
    CONTAINER_FIELD_NUMBER: _ClassVar[int]
    name: str
    vertices: PackedArray
    faces: PackedArray
    container: bool
    def __init__(self, name: _Optional[str] = ..., vertices: _Optional[_Union[PackedArray, _Mapping]] = ..., faces: _Optional[_Union[PackedArray, _Mapping]] = ..., container: _Optional[bool] = ...) -> None: ...

class SceneMeshes(_message.Message):
    __slots__ = ("header", "objects")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    header: Header
    objects: _containers.RepeatedCompositeFieldContainer[ObjectMesh]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., objects: _Optional[_Iterable[_Union[ObjectMesh, _Mapping]]] = ...) -> None: ...

class Hypothesis(_message.Message):
    __slots__ = ("name", "probability", "log_likelihood")
    NAME_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    LOG_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    name: str
    probability: float
    log_likelihood: float
    def __init__(self, name: _Optional[str] = ..., probability: _Optional[float] = ..., log_likelihood: _Optional[float] = ...) -> None: ...

class InferFillRequest(_message.Message):
    __slots__ = ("header", "session_id", "container", "fractions", "tracking")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    CONTAINER_FIELD_NUMBER: _ClassVar[int]
    FRACTIONS_FIELD_NUMBER: _ClassVar[int]
    TRACKING_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    container: str
    fractions: _containers.RepeatedScalarFieldContainer[float]
    tracking: TrackingMode
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., container: _Optional[str] = ..., fractions: _Optional[_Iterable[float]] = ..., tracking: _Optional[_Union[TrackingMode, str]] = ...) -> None: ...

class InferBlockageRequest(_message.Message):
    __slots__ = ("header", "session_id", "object", "tracking")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    TRACKING_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    object: str
    tracking: TrackingMode
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., object: _Optional[str] = ..., tracking: _Optional[_Union[TrackingMode, str]] = ...) -> None: ...

class InferenceReply(_message.Message):
    __slots__ = ("header", "session_id", "hypotheses", "best", "times_s", "probability_over_time", "frames", "wall_s")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    HYPOTHESES_FIELD_NUMBER: _ClassVar[int]
    BEST_FIELD_NUMBER: _ClassVar[int]
    TIMES_S_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_OVER_TIME_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    WALL_S_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    hypotheses: _containers.RepeatedCompositeFieldContainer[Hypothesis]
    best: str
    times_s: _containers.RepeatedScalarFieldContainer[float]
    probability_over_time: PackedArray
    frames: int
    wall_s: float
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., hypotheses: _Optional[_Iterable[_Union[Hypothesis, _Mapping]]] = ..., best: _Optional[str] = ..., times_s: _Optional[_Iterable[float]] = ..., probability_over_time: _Optional[_Union[PackedArray, _Mapping]] = ..., frames: _Optional[int] = ..., wall_s: _Optional[float] = ...) -> None: ...

class DiscrepancyRequest(_message.Message):
    __slots__ = ("header", "session_id", "camera", "candidates", "null_runs", "calibrate")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    NULL_RUNS_FIELD_NUMBER: _ClassVar[int]
    CALIBRATE_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    camera: str
    candidates: _containers.RepeatedScalarFieldContainer[str]
    null_runs: int
    calibrate: bool
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., camera: _Optional[str] = ..., candidates: _Optional[_Iterable[str]] = ..., null_runs: _Optional[int] = ..., calibrate: _Optional[bool] = ...) -> None: ...

class DiscrepancyReply(_message.Message):
    __slots__ = ("header", "session_id", "decision", "report_json", "model_json")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    DECISION_FIELD_NUMBER: _ClassVar[int]
    REPORT_JSON_FIELD_NUMBER: _ClassVar[int]
    MODEL_JSON_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    decision: str
    report_json: str
    model_json: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., decision: _Optional[str] = ..., report_json: _Optional[str] = ..., model_json: _Optional[str] = ...) -> None: ...

class LoadModelRequest(_message.Message):
    __slots__ = ("header", "session_id", "model_json")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MODEL_JSON_FIELD_NUMBER: _ClassVar[int]
    header: Header
    session_id: str
    model_json: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., session_id: _Optional[str] = ..., model_json: _Optional[str] = ...) -> None: ...
