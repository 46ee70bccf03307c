"""Typed values of the vamos client: scores, events, alarms, anomaly maps, camera info,
errors."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from . import _png


class VamosError(Exception):
    """Base class of every error this package raises."""


class SessionError(VamosError):
    """A gRPC call ended with a status other than OK.

    ``code`` is the gRPC status name (``"NOT_FOUND"``, ``"UNAUTHENTICATED"``, ...),
    ``details`` the server's message.
    """

    def __init__(self, code: str, details: str) -> None:
        super().__init__(f"{code}: {details}")
        self.code = code
        self.details = details


class EpisodeDamaged(VamosError):
    """An uploaded episode was cut short or corrupt: ``scores`` holds the frames scored
    before the damage, ``details`` what the server found."""

    def __init__(self, details: str, scores: list["FrameScore"]) -> None:
        super().__init__(f"episode damaged after {len(scores)} scored frame(s): {details}")
        self.details = details
        self.scores = scores


_DETECTORS = {1: "camera", 2: "body", 3: "flow", 4: "scene", 5: "kinematics"}
_EVENT_KINDS = {
    1: "opened",
    2: "warming_up",
    3: "frames_dropped",
    4: "message_error",
    5: "phase",
    6: "resumed",
    7: "reloaded",
}
_EDGES = {1: "started", 2: "ended"}


@dataclass(frozen=True)
class AnomalyMap:
    """A frame's anomaly map, decoded: 8-bit gray, 0 = nominal, 255 = full scale (the
    scene residual per cell at twice the profile's nominal spread when the profile is
    calibrated, else the flow predictor's squared error at 4x the alarm threshold)."""

    width: int
    height: int
    pixels: bytes
    """``height`` rows of ``width`` bytes, top row first."""

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``, as numpy orders it."""
        return self.height, self.width

    def array(self) -> Any:
        """The map as a read-only numpy ``uint8`` array of :attr:`shape` (needs numpy:
        ``pip install 'vamos-client[client]'``)."""
        import numpy as np

        return np.frombuffer(self.pixels, dtype=np.uint8).reshape(self.height, self.width)

    def at(self, x: int, y: int) -> int:
        """The value of pixel ``(x, y)`` (column, row), 0-255."""
        if not (0 <= x < self.width and 0 <= y < self.height):
            raise IndexError(f"({x}, {y}) is outside the {self.width}x{self.height} map")
        return self.pixels[y * self.width + x]

    @classmethod
    def from_png(cls, data: bytes) -> "AnomalyMap":
        """Decodes the PNG the server sends (8-bit gray); :class:`ValueError` for any
        other image."""
        width, height, pixels = _png.decode_gray8(data)
        return cls(width, height, pixels)


@dataclass(frozen=True)
class FrameScore:
    """The score of one processed frame, as the server sent it."""

    stamp_ns: int
    """Image stamp, nanoseconds."""
    index: int
    """Index of the image in the stream (0-based, counting images the stride skips)."""
    frame: int
    """Index among processed frames."""
    score: float
    """The fused anomaly score."""
    e_c: Optional[float]
    """Camera-motion error, pixels (None: not computed for this frame)."""
    e_b: Optional[float]
    """Body-motion error, pixels."""
    e_o: Optional[float]
    """Flow-prediction error of the learned predictor."""
    anomaly: bool
    """Whether the frame is flagged anomalous."""
    detector: Optional[str]
    """Which detector set the score: ``"camera"``, ``"body"``, ``"flow"``, ``"scene"``, ``"kinematics"`` or None."""
    warming_up: bool
    """The flow predictor is still collecting its history."""
    e_r: Optional[float] = None
    """Scene-motion residual (pooled, normalised by nominal per-cell statistics)."""
    e_k: Optional[float] = None
    """Kinematic novelty: distance from the robot's state to the nearest nominal one (in nominal
    joint ranges; metres with ``state = "links"``)."""
    latency_s: float = 0.0
    """Server time from the image's arrival to its score, seconds."""
    compute_s: float = 0.0
    """Time spent computing the score, seconds."""
    frames_lost: int = 0
    """Images of the session lost (dropped by a full queue, or refused) between the
    previous score and this frame; when above 0 the motion history started afresh here."""
    anomaly_map: Optional[bytes] = field(default=None, repr=False)
    """The frame's anomaly map as the PNG the server sent (sessions opened with
    ``anomaly_maps=True``, frames that have one), else None. Decoded by
    :meth:`anomaly_map_image` and :meth:`anomaly_map_array`."""

    def anomaly_map_image(self) -> Optional[AnomalyMap]:
        """The anomaly map decoded (width, height, pixels; no numpy needed), or None
        when this frame has none. :class:`ValueError` if the bytes are not the server's
        8-bit gray PNG."""
        return AnomalyMap.from_png(self.anomaly_map) if self.anomaly_map else None

    def anomaly_map_array(self) -> Any:
        """The anomaly map as a numpy ``uint8`` array of shape ``(height, width)``, or
        None when this frame has none (needs numpy)."""
        m = self.anomaly_map_image()
        return m.array() if m is not None else None

    @classmethod
    def from_proto(cls, m: Any) -> "FrameScore":
        def opt(name: str) -> Optional[float]:
            return float(getattr(m, name)) if m.HasField(name) else None

        return cls(
            stamp_ns=int(m.stamp_ns),
            index=int(m.index),
            frame=int(m.frame),
            score=float(m.score),
            e_c=opt("e_c"),
            e_b=opt("e_b"),
            e_o=opt("e_o"),
            anomaly=bool(m.anomaly),
            detector=_DETECTORS.get(int(m.detector)),
            warming_up=bool(m.warming_up),
            e_r=opt("e_r"),
            e_k=opt("e_k"),
            latency_s=float(m.latency_s),
            compute_s=float(m.compute_s),
            frames_lost=int(m.frames_lost),
            anomaly_map=bytes(m.anomaly_map) or None,
        )

    def to_dict(self) -> dict[str, Any]:
        """The score as JSON-ready values (without the anomaly map)."""
        return {
            "stamp_ns": self.stamp_ns, "index": self.index, "frame": self.frame,
            "score": self.score, "e_c": self.e_c, "e_b": self.e_b, "e_o": self.e_o,
            "e_r": self.e_r, "e_k": self.e_k, "anomaly": self.anomaly, "detector": self.detector,
            "warming_up": self.warming_up, "latency_s": self.latency_s,
            "compute_s": self.compute_s, "frames_lost": self.frames_lost,
        }


def _opt(m: Any, name: str) -> Optional[float]:
    return float(getattr(m, name)) if m.HasField(name) else None


@dataclass(frozen=True)
class AlarmComponents:
    """Every detector's value at one frame of an alarm (None: off, not yet defined)."""

    stamp_ns: int = 0
    """Image stamp, nanoseconds."""
    score: Optional[float] = None
    """The fused score."""
    e_c: Optional[float] = None
    e_b: Optional[float] = None
    e_o: Optional[float] = None
    e_r: Optional[float] = None
    e_k: Optional[float] = None

    @classmethod
    def from_proto(cls, m: Any) -> "AlarmComponents":
        return cls(stamp_ns=int(m.stamp_ns), score=_opt(m, "score"), e_c=_opt(m, "e_c"), e_b=_opt(m, "e_b"),
                   e_o=_opt(m, "e_o"), e_r=_opt(m, "e_r"), e_k=_opt(m, "e_k"))

    def to_dict(self) -> dict[str, Any]:
        return {"stamp_ns": self.stamp_ns, "score": self.score, "e_c": self.e_c, "e_b": self.e_b,
                "e_o": self.e_o, "e_r": self.e_r, "e_k": self.e_k}


@dataclass(frozen=True)
class AlarmThresholds:
    """The thresholds in force when an alarm started: the fused score's (``alarm``) and
    each detector's own, in its units (None: none, the detector alone never alarms).
    The same keys as the ``thresholds`` of an alarm listed by ``GET /v1/alarms``."""

    alarm: Optional[float] = None
    e_c: Optional[float] = None
    e_b: Optional[float] = None
    e_o: Optional[float] = None
    e_r: Optional[float] = None
    e_k: Optional[float] = None

    def to_dict(self) -> dict[str, Any]:
        return {"alarm": self.alarm, "e_c": self.e_c, "e_b": self.e_b, "e_o": self.e_o, "e_r": self.e_r,
                "e_k": self.e_k}


@dataclass(frozen=True)
class AlarmEvent:
    """An alarm started or ended (``vamos.v1.AlarmEvent``): the server debounces the
    per-frame anomaly flags (k of the last n frames start an alarm, n clear frames in a
    row end it; the profile's ``[alarm_events]``, default 3 of 5) and sends each edge
    right after the score of the frame that caused it.

    ``alarm_id`` is the id of the REST API (``AdminClient.alarm``,
    ``AdminClient.mark_false_alarm``). Like :class:`SessionEvent` it has ``kind``,
    ``session_id``, ``detail`` and ``stamp_ns``, so code that logs every update that is
    not a score by those keeps working."""

    edge: str
    """``"started"``, ``"ended"`` (or ``"unknown"``)."""
    alarm_id: str
    session_id: str
    detector: Optional[str]
    """The detector that fired at its start (``"camera"``, ``"body"``, ``"flow"``, ``"scene"``,
    ``"kinematics"``)."""
    detectors: tuple[str, ...] = ()
    """Every detector that fired during it so far, in the order they first did."""
    start_frame: int = 0
    """Processed-frame index of its start (:attr:`FrameScore.frame`)."""
    end_frame: Optional[int] = None
    """Processed-frame index of its end (ended alarms)."""
    end_stamp_ns: Optional[int] = None
    """Image stamp of its end, nanoseconds (ended alarms)."""
    frames_flagged: int = 0
    """Anomalous frames so far."""
    thresholds: AlarmThresholds = AlarmThresholds()
    start: AlarmComponents = AlarmComponents()
    """Every component at its start frame."""
    peak: AlarmComponents = AlarmComponents()
    """Every component at its highest-scoring frame so far."""

    @property
    def started(self) -> bool:
        return self.edge == "started"

    @property
    def ended(self) -> bool:
        return self.edge == "ended"

    @property
    def kind(self) -> str:
        """``"alarm_started"`` or ``"alarm_ended"`` (``"alarm_unknown"``)."""
        return f"alarm_{self.edge}"

    @property
    def stamp_ns(self) -> int:
        """The image stamp of the edge: its end for an ended alarm, else its start."""
        if self.ended and self.end_stamp_ns is not None:
            return self.end_stamp_ns
        return self.start.stamp_ns

    @property
    def detail(self) -> str:
        """One line for logs."""
        if self.ended:
            return (f"alarm {self.alarm_id} ended at frame {self.end_frame} after {self.frames_flagged} "
                    f"flagged frame(s) ({', '.join(self.detectors) or self.detector})")
        return f"alarm {self.alarm_id} started at frame {self.start_frame} ({self.detector})"

    @classmethod
    def from_proto(cls, m: Any) -> "AlarmEvent":
        return cls(
            edge=_EDGES.get(int(m.edge), "unknown"),
            alarm_id=str(m.alarm_id),
            session_id=str(m.session_id),
            detector=_DETECTORS.get(int(m.detector)),
            detectors=tuple(_DETECTORS.get(int(d), "unknown") for d in m.detectors),
            start_frame=int(m.start_frame),
            end_frame=int(m.end_frame) if m.HasField("end_frame") else None,
            end_stamp_ns=int(m.end_stamp_ns) if m.HasField("end_stamp_ns") else None,
            frames_flagged=int(m.frames_flagged),
            thresholds=AlarmThresholds(
                alarm=_opt(m, "alarm_threshold"), e_c=_opt(m, "e_c_threshold"), e_b=_opt(m, "e_b_threshold"),
                e_o=_opt(m, "e_o_threshold"), e_r=_opt(m, "e_r_threshold"), e_k=_opt(m, "e_k_threshold")),
            start=AlarmComponents.from_proto(m.start) if m.HasField("start") else AlarmComponents(),
            peak=AlarmComponents.from_proto(m.peak) if m.HasField("peak") else AlarmComponents(),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "edge": self.edge, "alarm_id": self.alarm_id, "session_id": self.session_id,
            "detector": self.detector, "detectors": list(self.detectors), "start_frame": self.start_frame,
            "end_frame": self.end_frame, "end_stamp_ns": self.end_stamp_ns,
            "frames_flagged": self.frames_flagged, "thresholds": self.thresholds.to_dict(),
            "start": self.start.to_dict(), "peak": self.peak.to_dict(),
        }


@dataclass(frozen=True)
class SessionEvent:
    """Something the server reports about a session (opened, frames dropped, ...)."""

    kind: str
    """``opened``, ``warming_up``, ``frames_dropped``, ``message_error``, ``phase``,
    ``resumed``, ``reloaded`` (or ``unknown``)."""
    session_id: str
    detail: str
    stamp_ns: int = 0
    """Stamp of the message concerned, if any."""
    count: int = 0
    """``frames_dropped``: images dropped so far; ``reloaded``: reloads so far."""

    @classmethod
    def from_proto(cls, m: Any) -> "SessionEvent":
        return cls(
            kind=_EVENT_KINDS.get(int(m.kind), "unknown"),
            session_id=str(m.session_id),
            detail=str(m.detail),
            stamp_ns=int(m.stamp_ns),
            count=int(m.count),
        )

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "session_id": self.session_id, "detail": self.detail,
                "stamp_ns": self.stamp_ns, "count": self.count}


@dataclass(frozen=True)
class CameraInfo:
    """Pinhole intrinsics of the camera, pixels, at the given image size."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_k(cls, width: int, height: int, k: Any) -> "CameraInfo":
        """From a ROS ``CameraInfo`` K matrix (row-major 3x3)."""
        k = list(k)
        if len(k) != 9:
            raise ValueError(f"K has {len(k)} entries, expected 9")
        return cls(int(width), int(height), float(k[0]), float(k[4]), float(k[2]), float(k[5]))

    def to_proto(self, pb: Any) -> Any:
        return pb.CameraInfo(width=self.width, height=self.height, fx=self.fx, fy=self.fy,
                             cx=self.cx, cy=self.cy)


@dataclass
class SessionSummary:
    """What a replayed session produced."""

    session_id: str = ""
    images_sent: int = 0
    scores: list[FrameScore] = field(default_factory=list)
    events: list[SessionEvent] = field(default_factory=list)
    alarms: list[AlarmEvent] = field(default_factory=list)
    """Every alarm start and end, in stream order."""
    dropped: int = 0
    """Images the server dropped under backpressure (its running count)."""
    message_errors: list[str] = field(default_factory=list)
    reconnects: int = 0
    """Times the stream broke and the session was resumed."""
    elapsed_s: float = 0.0
