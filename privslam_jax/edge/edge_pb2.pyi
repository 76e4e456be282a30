from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class TrackingState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TRACKING_STATE_UNSPECIFIED: _ClassVar[TrackingState]
    TRACKED: _ClassVar[TrackingState]
    LOST: _ClassVar[TrackingState]
TRACKING_STATE_UNSPECIFIED: TrackingState
TRACKED: TrackingState
LOST: TrackingState

class Calibration(_message.Message):
    __slots__ = ("session_id", "mode", "fx", "fy", "cx", "cy", "width", "height", "baseline", "seed", "ignore_masked")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    BASELINE_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    IGNORE_MASKED_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    mode: str
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    baseline: float
    seed: int
    ignore_masked: bool
    def __init__(self, session_id: _Optional[str] = ..., mode: _Optional[str] = ..., fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., baseline: _Optional[float] = ..., seed: _Optional[int] = ..., ignore_masked: _Optional[bool] = ...) -> None: ...

class Frame(_message.Message):
    __slots__ = ("index", "timestamp", "image", "right", "depth", "mask")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    RIGHT_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    MASK_FIELD_NUMBER: _ClassVar[int]
    index: int
    timestamp: float
    image: bytes
    right: bytes
    depth: bytes
    mask: bytes
    def __init__(self, index: _Optional[int] = ..., timestamp: _Optional[float] = ..., image: _Optional[bytes] = ..., right: _Optional[bytes] = ..., depth: _Optional[bytes] = ..., mask: _Optional[bytes] = ...) -> None: ...

class TrajectoryRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class MapRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class Up(_message.Message):
    __slots__ = ("calibration", "frame", "trajectory_request", "map_request")
    CALIBRATION_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    TRAJECTORY_REQUEST_FIELD_NUMBER: _ClassVar[int]
    MAP_REQUEST_FIELD_NUMBER: _ClassVar[int]
    calibration: Calibration
    frame: Frame
    trajectory_request: TrajectoryRequest
    map_request: MapRequest
    def __init__(self, calibration: _Optional[_Union[Calibration, _Mapping]] = ..., frame: _Optional[_Union[Frame, _Mapping]] = ..., trajectory_request: _Optional[_Union[TrajectoryRequest, _Mapping]] = ..., map_request: _Optional[_Union[MapRequest, _Mapping]] = ...) -> None: ...

class Started(_message.Message):
    __slots__ = ("session_id", "next_index")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    NEXT_INDEX_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    next_index: int
    def __init__(self, session_id: _Optional[str] = ..., next_index: _Optional[int] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("index", "timestamp", "T_w_c", "state", "inliers", "map_id")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    T_W_C_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    INLIERS_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    index: int
    timestamp: float
    T_w_c: _containers.RepeatedScalarFieldContainer[float]
    state: TrackingState
    inliers: int
    map_id: int
    def __init__(self, index: _Optional[int] = ..., timestamp: _Optional[float] = ..., T_w_c: _Optional[_Iterable[float]] = ..., state: _Optional[_Union[TrackingState, str]] = ..., inliers: _Optional[int] = ..., map_id: _Optional[int] = ...) -> None: ...

class Trajectory(_message.Message):
    __slots__ = ("poses",)
    POSES_FIELD_NUMBER: _ClassVar[int]
    poses: _containers.RepeatedCompositeFieldContainer[Pose]
    def __init__(self, poses: _Optional[_Iterable[_Union[Pose, _Mapping]]] = ...) -> None: ...

class LineCloud(_message.Message):
    __slots__ = ("ply", "lines", "frames")
    PLY_FIELD_NUMBER: _ClassVar[int]
    LINES_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    ply: bytes
    lines: int
    frames: int
    def __init__(self, ply: _Optional[bytes] = ..., lines: _Optional[int] = ..., frames: _Optional[int] = ...) -> None: ...

class Down(_message.Message):
    __slots__ = ("started", "pose", "trajectory", "line_cloud")
    STARTED_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    TRAJECTORY_FIELD_NUMBER: _ClassVar[int]
    LINE_CLOUD_FIELD_NUMBER: _ClassVar[int]
    started: Started
    pose: Pose
    trajectory: Trajectory
    line_cloud: LineCloud
    def __init__(self, started: _Optional[_Union[Started, _Mapping]] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., trajectory: _Optional[_Union[Trajectory, _Mapping]] = ..., line_cloud: _Optional[_Union[LineCloud, _Mapping]] = ...) -> None: ...
