"""What the ROS 2 bridge computes, without ROS: incoming messages as ``vamos.v1``
requests (duck-typed: anything with the fields of ``sensor_msgs`` messages), and the
bridge's state as the values of its outputs (``/vamos/score``, ``/vamos/anomaly`` and a
``diagnostic_msgs/DiagnosticArray`` status)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Optional

from vamos.client import CameraInfo, FrameScore, SessionEvent
from vamos.client import _convert
from vamos.v1 import monitor_pb2 as pb

# diagnostic_msgs/DiagnosticStatus levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3


def image_request(msg: Any) -> Any:
    """A ``StreamRequest`` for a ``sensor_msgs/Image`` or ``CompressedImage`` (told apart
    by the ``format`` field)."""
    if hasattr(msg, "format") and not hasattr(msg, "encoding"):
        return pb.StreamRequest(image=_convert.ros_compressed_image(msg))
    return pb.StreamRequest(image=_convert.ros_image(msg))


def joints_request(msg: Any) -> Any:
    """A ``StreamRequest`` for a ``sensor_msgs/JointState``."""
    return pb.StreamRequest(joints=_convert.ros_joint_state(msg))


def camera_info(msg: Any) -> CameraInfo:
    """The intrinsics of a ``sensor_msgs/CameraInfo``."""
    return CameraInfo.from_k(msg.width, msg.height, msg.k)


@dataclass
class BridgeState:
    """What the bridge knows about its session, for its outputs."""

    session_id: str = ""
    connected: bool = False
    images_sent: int = 0
    frames_scored: int = 0
    dropped: int = 0
    refused: int = 0
    reconnects: int = 0
    warming_up: bool = True
    latest: Optional[FrameScore] = None
    last_error: str = ""
    last_image_wall: Optional[float] = None
    last_score_wall: Optional[float] = None
    events: list[str] = field(default_factory=list)

    def on_sent_image(self, now: Optional[float] = None) -> None:
        self.images_sent += 1
        self.last_image_wall = time.monotonic() if now is None else now

    def on_update(self, u: Any, now: Optional[float] = None) -> Optional[tuple[float, bool]]:
        """Records a score or event; for a score returns what to publish: ``(score,
        anomaly)``."""
        if isinstance(u, FrameScore):
            self.frames_scored += 1
            self.latest = u
            self.warming_up = u.warming_up
            self.last_score_wall = time.monotonic() if now is None else now
            return u.score, u.anomaly
        if isinstance(u, SessionEvent):
            if u.kind in ("opened", "resumed", "reloaded"):
                self.session_id = u.session_id
                self.connected = True
            elif u.kind == "frames_dropped":
                self.dropped = max(self.dropped, u.count)
            elif u.kind == "message_error":
                self.refused += 1
                self.last_error = u.detail
            self.events = (self.events + [f"{u.kind}: {u.detail}"])[-10:]
        return None

    def diagnostic(self, now: Optional[float] = None, stale_after_s: float = 5.0) -> tuple[int, str, list[tuple[str, str]]]:
        """``(level, message, key-values)`` of the bridge's DiagnosticStatus."""
        now = time.monotonic() if now is None else now
        values = [
            ("session_id", self.session_id),
            ("images_sent", str(self.images_sent)),
            ("frames_scored", str(self.frames_scored)),
            ("dropped", str(self.dropped)),
            ("refused", str(self.refused)),
            ("reconnects", str(self.reconnects)),
        ]
        if self.latest is not None:
            values += [("score", repr(self.latest.score)), ("anomaly", str(self.latest.anomaly)),
                       ("latency_s", f"{self.latest.latency_s:.4f}")]
        if not self.connected:
            return ERROR, f"not connected to vamos{': ' + self.last_error if self.last_error else ''}", values
        if self.last_image_wall is None or now - self.last_image_wall > stale_after_s:
            return STALE, "no images from the camera topic", values
        if self.last_score_wall is None or now - self.last_score_wall > stale_after_s:
            return WARN, "images sent but no scores back", values
        if self.dropped or self.refused:
            return WARN, f"{self.dropped} image(s) dropped, {self.refused} message(s) refused", values
        if self.warming_up:
            return OK, "scoring (flow predictor warming up)", values
        return OK, "scoring", values
