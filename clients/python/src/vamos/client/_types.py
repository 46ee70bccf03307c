"""Typed values of the vamos client: scores, events, camera info, errors."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional


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
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "stamp_ns": self.stamp_ns, "index": self.index, "frame": self.frame,
            "score": self.score, "e_c": self.e_c, "e_b": self.e_b, "e_o": self.e_o,
            "e_r": self.e_r, "e_k": self.e_k, "anomaly": self.anomaly, "detector": self.detector,
            "warming_up": self.warming_up, "latency_s": self.latency_s,
            "compute_s": self.compute_s,
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
    dropped: int = 0
    """Images the server dropped under backpressure (its running count)."""
    message_errors: list[str] = field(default_factory=list)
    reconnects: int = 0
    """Times the stream broke and the session was resumed."""
    elapsed_s: float = 0.0
