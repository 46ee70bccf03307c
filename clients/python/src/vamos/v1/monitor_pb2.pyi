from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Detector(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DETECTOR_UNSPECIFIED: _ClassVar[Detector]
    DETECTOR_CAMERA: _ClassVar[Detector]
    DETECTOR_BODY: _ClassVar[Detector]
    DETECTOR_FLOW: _ClassVar[Detector]
    DETECTOR_SCENE: _ClassVar[Detector]
    DETECTOR_KINEMATICS: _ClassVar[Detector]
DETECTOR_UNSPECIFIED: Detector
DETECTOR_CAMERA: Detector
DETECTOR_BODY: Detector
DETECTOR_FLOW: Detector
DETECTOR_SCENE: Detector
DETECTOR_KINEMATICS: Detector

class StreamRequest(_message.Message):
    __slots__ = ("open", "image", "joints", "phase")
    OPEN_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    JOINTS_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    open: OpenSession
    image: Image
    joints: JointState
    phase: PhaseMarker
    def __init__(self, open: _Optional[_Union[OpenSession, _Mapping]] = ..., image: _Optional[_Union[Image, _Mapping]] = ..., joints: _Optional[_Union[JointState, _Mapping]] = ..., phase: _Optional[_Union[PhaseMarker, _Mapping]] = ...) -> None: ...

class OpenSession(_message.Message):
    __slots__ = ("robot_id", "profile", "camera_info", "task", "session_id", "anomaly_maps", "image_rate_hz")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    PROFILE_FIELD_NUMBER: _ClassVar[int]
    CAMERA_INFO_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    ANOMALY_MAPS_FIELD_NUMBER: _ClassVar[int]
    IMAGE_RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    profile: str
    camera_info: CameraInfo
    task: str
    session_id: str
    anomaly_maps: bool
    image_rate_hz: float
    def __init__(self, robot_id: _Optional[str] = ..., profile: _Optional[str] = ..., camera_info: _Optional[_Union[CameraInfo, _Mapping]] = ..., task: _Optional[str] = ..., session_id: _Optional[str] = ..., anomaly_maps: _Optional[bool] = ..., image_rate_hz: _Optional[float] = ...) -> None: ...

class CameraInfo(_message.Message):
    __slots__ = ("width", "height", "fx", "fy", "cx", "cy")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ...) -> None: ...

class Image(_message.Message):
    __slots__ = ("stamp_ns", "encoding", "width", "height", "step", "big_endian", "data", "depth")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    BIG_ENDIAN_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    encoding: str
    width: int
    height: int
    step: int
    big_endian: bool
    data: bytes
    depth: DepthImage
    def __init__(self, stamp_ns: _Optional[int] = ..., encoding: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., step: _Optional[int] = ..., big_endian: _Optional[bool] = ..., data: _Optional[bytes] = ..., depth: _Optional[_Union[DepthImage, _Mapping]] = ...) -> None: ...

class DepthImage(_message.Message):
    __slots__ = ("encoding", "width", "height", "step", "big_endian", "data")
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    BIG_ENDIAN_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    encoding: str
    width: int
    height: int
    step: int
    big_endian: bool
    data: bytes
    def __init__(self, encoding: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., step: _Optional[int] = ..., big_endian: _Optional[bool] = ..., data: _Optional[bytes] = ...) -> None: ...

class JointState(_message.Message):
    __slots__ = ("stamp_ns", "names", "positions", "velocities", "efforts")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    NAMES_FIELD_NUMBER: _ClassVar[int]
    POSITIONS_FIELD_NUMBER: _ClassVar[int]
    VELOCITIES_FIELD_NUMBER: _ClassVar[int]
    EFFORTS_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    names: _containers.RepeatedScalarFieldContainer[str]
    positions: _containers.RepeatedScalarFieldContainer[float]
    velocities: _containers.RepeatedScalarFieldContainer[float]
    efforts: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, stamp_ns: _Optional[int] = ..., names: _Optional[_Iterable[str]] = ..., positions: _Optional[_Iterable[float]] = ..., velocities: _Optional[_Iterable[float]] = ..., efforts: _Optional[_Iterable[float]] = ...) -> None: ...

class PhaseMarker(_message.Message):
    __slots__ = ("stamp_ns", "phase")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    phase: str
    def __init__(self, stamp_ns: _Optional[int] = ..., phase: _Optional[str] = ...) -> None: ...

class StreamResponse(_message.Message):
    __slots__ = ("score", "event", "alarm")
    SCORE_FIELD_NUMBER: _ClassVar[int]
    EVENT_FIELD_NUMBER: _ClassVar[int]
    ALARM_FIELD_NUMBER: _ClassVar[int]
    score: FrameScore
    event: SessionEvent
    alarm: AlarmEvent
    def __init__(self, score: _Optional[_Union[FrameScore, _Mapping]] = ..., event: _Optional[_Union[SessionEvent, _Mapping]] = ..., alarm: _Optional[_Union[AlarmEvent, _Mapping]] = ...) -> None: ...

class FrameScore(_message.Message):
    __slots__ = ("stamp_ns", "index", "frame", "score", "e_c", "e_b", "e_o", "anomaly", "detector", "warming_up", "latency_s", "compute_s", "e_r", "anomaly_map", "e_k", "frames_lost")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    E_C_FIELD_NUMBER: _ClassVar[int]
    E_B_FIELD_NUMBER: _ClassVar[int]
    E_O_FIELD_NUMBER: _ClassVar[int]
    ANOMALY_FIELD_NUMBER: _ClassVar[int]
    DETECTOR_FIELD_NUMBER: _ClassVar[int]
    WARMING_UP_FIELD_NUMBER: _ClassVar[int]
    LATENCY_S_FIELD_NUMBER: _ClassVar[int]
    COMPUTE_S_FIELD_NUMBER: _ClassVar[int]
    E_R_FIELD_NUMBER: _ClassVar[int]
    ANOMALY_MAP_FIELD_NUMBER: _ClassVar[int]
    E_K_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LOST_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    index: int
    frame: int
    score: float
    e_c: float
    e_b: float
    e_o: float
    anomaly: bool
    detector: Detector
    warming_up: bool
    latency_s: float
    compute_s: float
    e_r: float
    anomaly_map: bytes
    e_k: float
    frames_lost: int
    def __init__(self, stamp_ns: _Optional[int] = ..., index: _Optional[int] = ..., frame: _Optional[int] = ..., score: _Optional[float] = ..., e_c: _Optional[float] = ..., e_b: _Optional[float] = ..., e_o: _Optional[float] = ..., anomaly: _Optional[bool] = ..., detector: _Optional[_Union[Detector, str]] = ..., warming_up: _Optional[bool] = ..., latency_s: _Optional[float] = ..., compute_s: _Optional[float] = ..., e_r: _Optional[float] = ..., anomaly_map: _Optional[bytes] = ..., e_k: _Optional[float] = ..., frames_lost: _Optional[int] = ...) -> None: ...

class AlarmComponents(_message.Message):
    __slots__ = ("stamp_ns", "score", "e_c", "e_b", "e_o", "e_r", "e_k")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    E_C_FIELD_NUMBER: _ClassVar[int]
    E_B_FIELD_NUMBER: _ClassVar[int]
    E_O_FIELD_NUMBER: _ClassVar[int]
    E_R_FIELD_NUMBER: _ClassVar[int]
    E_K_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    score: float
    e_c: float
    e_b: float
    e_o: float
    e_r: float
    e_k: float
    def __init__(self, stamp_ns: _Optional[int] = ..., score: _Optional[float] = ..., e_c: _Optional[float] = ..., e_b: _Optional[float] = ..., e_o: _Optional[float] = ..., e_r: _Optional[float] = ..., e_k: _Optional[float] = ...) -> None: ...

class AlarmEvent(_message.Message):
    __slots__ = ("edge", "alarm_id", "session_id", "detector", "detectors", "start_frame", "end_frame", "end_stamp_ns", "frames_flagged", "alarm_threshold", "e_c_threshold", "e_b_threshold", "start", "peak", "e_o_threshold", "e_r_threshold", "e_k_threshold")
    class Edge(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        EDGE_UNSPECIFIED: _ClassVar[AlarmEvent.Edge]
        EDGE_STARTED: _ClassVar[AlarmEvent.Edge]
        EDGE_ENDED: _ClassVar[AlarmEvent.Edge]
    EDGE_UNSPECIFIED: AlarmEvent.Edge
    EDGE_STARTED: AlarmEvent.Edge
    EDGE_ENDED: AlarmEvent.Edge
    EDGE_FIELD_NUMBER: _ClassVar[int]
    ALARM_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    DETECTOR_FIELD_NUMBER: _ClassVar[int]
    DETECTORS_FIELD_NUMBER: _ClassVar[int]
    START_FRAME_FIELD_NUMBER: _ClassVar[int]
    END_FRAME_FIELD_NUMBER: _ClassVar[int]
    END_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FLAGGED_FIELD_NUMBER: _ClassVar[int]
    ALARM_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    E_C_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    E_B_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    START_FIELD_NUMBER: _ClassVar[int]
    PEAK_FIELD_NUMBER: _ClassVar[int]
    E_O_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    E_R_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    E_K_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    edge: AlarmEvent.Edge
    alarm_id: str
    session_id: str
    detector: Detector
    detectors: _containers.RepeatedScalarFieldContainer[Detector]
    start_frame: int
    end_frame: int
    end_stamp_ns: int
    frames_flagged: int
    alarm_threshold: float
    e_c_threshold: float
    e_b_threshold: float
    start: AlarmComponents
    peak: AlarmComponents
    e_o_threshold: float
    e_r_threshold: float
    e_k_threshold: float
    def __init__(self, edge: _Optional[_Union[AlarmEvent.Edge, str]] = ..., alarm_id: _Optional[str] = ..., session_id: _Optional[str] = ..., detector: _Optional[_Union[Detector, str]] = ..., detectors: _Optional[_Iterable[_Union[Detector, str]]] = ..., start_frame: _Optional[int] = ..., end_frame: _Optional[int] = ..., end_stamp_ns: _Optional[int] = ..., frames_flagged: _Optional[int] = ..., alarm_threshold: _Optional[float] = ..., e_c_threshold: _Optional[float] = ..., e_b_threshold: _Optional[float] = ..., start: _Optional[_Union[AlarmComponents, _Mapping]] = ..., peak: _Optional[_Union[AlarmComponents, _Mapping]] = ..., e_o_threshold: _Optional[float] = ..., e_r_threshold: _Optional[float] = ..., e_k_threshold: _Optional[float] = ...) -> None: ...

class SessionEvent(_message.Message):
    __slots__ = ("kind", "session_id", "detail", "stamp_ns", "count")
    class Kind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        KIND_UNSPECIFIED: _ClassVar[SessionEvent.Kind]
        KIND_OPENED: _ClassVar[SessionEvent.Kind]
        KIND_WARMING_UP: _ClassVar[SessionEvent.Kind]
        KIND_FRAMES_DROPPED: _ClassVar[SessionEvent.Kind]
        KIND_MESSAGE_ERROR: _ClassVar[SessionEvent.Kind]
        KIND_PHASE: _ClassVar[SessionEvent.Kind]
        KIND_RESUMED: _ClassVar[SessionEvent.Kind]
        KIND_RELOADED: _ClassVar[SessionEvent.Kind]
    KIND_UNSPECIFIED: SessionEvent.Kind
    KIND_OPENED: SessionEvent.Kind
    KIND_WARMING_UP: SessionEvent.Kind
    KIND_FRAMES_DROPPED: SessionEvent.Kind
    KIND_MESSAGE_ERROR: SessionEvent.Kind
    KIND_PHASE: SessionEvent.Kind
    KIND_RESUMED: SessionEvent.Kind
    KIND_RELOADED: SessionEvent.Kind
    KIND_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    kind: SessionEvent.Kind
    session_id: str
    detail: str
    stamp_ns: int
    count: int
    def __init__(self, kind: _Optional[_Union[SessionEvent.Kind, str]] = ..., session_id: _Optional[str] = ..., detail: _Optional[str] = ..., stamp_ns: _Optional[int] = ..., count: _Optional[int] = ...) -> None: ...

class EpisodeChunk(_message.Message):
    __slots__ = ("profile", "data", "name")
    PROFILE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    profile: str
    data: bytes
    name: str
    def __init__(self, profile: _Optional[str] = ..., data: _Optional[bytes] = ..., name: _Optional[str] = ...) -> None: ...
