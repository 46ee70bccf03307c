"""ROS 2 messages to vamos requests and vamos scores to ROS 2 messages, without ROS:
messages are duck-typed (anything with the fields of ``sensor_msgs`` messages), and
outgoing messages are described as plain values the node copies into the real types.

Alarm events (``vamos_msgs/AlarmEvent``) are stamped with the image at which the alarm
started or ended, and anomaly maps (``sensor_msgs/Image``, ``mono8``) with their score's
image, so both line up with the images and scores like the scores do.

Stamps: a vamos score carries the stamp of the image it scored (``stamp_ns``, the
image's ``header.stamp`` in nanoseconds); :func:`stamp_from_ns` turns it back into a
``builtin_interfaces/Time`` so a ``vamos_msgs/FrameScore`` has the image's header and can
be synchronised with it (``message_filters``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Optional

from vamos.client import AlarmComponents, AlarmEvent, CameraInfo, FrameScore
from vamos.client import _convert
from vamos.v1 import monitor_pb2 as pb

_NS = 1_000_000_000
#: builtin_interfaces/Time: int32 sec, uint32 nanosec.
_SEC_MIN, _SEC_MAX = -(2**31), 2**31 - 1


def image_request(msg: Any) -> Any:
    """A ``StreamRequest`` for a ``sensor_msgs/Image`` or ``CompressedImage`` (told apart
    by the ``format`` field); :class:`ValueError` for a compressed format vamos cannot
    decode."""
    if hasattr(msg, "format") and not hasattr(msg, "encoding"):
        return pb.StreamRequest(image=_convert.ros_compressed_image(msg))
    return pb.StreamRequest(image=_convert.ros_image(msg))


def depth_image(msg: Any) -> Any:
    """A ``vamos.v1.DepthImage`` of a ``sensor_msgs/Image``, its rows as they came: the
    server checks the encoding (16UC1 millimetres or 32FC1 metres) and refuses another
    for that frame with a message."""
    return _convert.ros_depth(msg)


def with_depth(request: Any, depth: Any) -> Any:
    """``request`` (an image's ``StreamRequest``) carrying ``depth``, when not None."""
    if depth is not None:
        request.image.depth.CopyFrom(depth)
    return request


def joints_request(msg: Any) -> Any:
    """A ``StreamRequest`` for a ``sensor_msgs/JointState``."""
    return pb.StreamRequest(joints=_convert.ros_joint_state(msg))


def camera_info(msg: Any) -> CameraInfo:
    """The intrinsics of a ``sensor_msgs/CameraInfo``; :class:`ValueError` when they are
    not usable: an uncalibrated camera (``k`` all zeros, the ROS convention), a
    non-positive or non-finite focal length, a centre that is not finite, or no size."""
    info = CameraInfo.from_k(msg.width, msg.height, msg.k)
    if not all(math.isfinite(x) for x in (info.fx, info.fy, info.cx, info.cy)):
        raise ValueError(f"camera matrix K has non-finite entries: {list(msg.k)}")
    if info.fx <= 0 or info.fy <= 0:
        raise ValueError(f"camera matrix K has no positive focal lengths (fx {info.fx}, fy {info.fy}): "
                         "an uncalibrated camera")
    if info.width <= 0 or info.height <= 0:
        raise ValueError(f"camera info without an image size ({info.width}x{info.height})")
    return info


def stamp_ns(msg: Any) -> int:
    """``header.stamp`` of a message, nanoseconds."""
    return _convert.ros_stamp_ns(msg)


class Stamp(NamedTuple):
    """A ``builtin_interfaces/Time``."""

    sec: int
    nanosec: int


def stamp_from_ns(ns: int) -> Stamp:
    """The ``builtin_interfaces/Time`` of ``ns`` nanoseconds (exact: ``sec * 1e9 +
    nanosec == ns``, ``0 <= nanosec < 1e9``, also before 1970); :class:`ValueError`
    outside ``sec``'s int32 range."""
    sec, nanosec = divmod(int(ns), _NS)
    if not _SEC_MIN <= sec <= _SEC_MAX:
        raise ValueError(f"stamp {ns} ns is outside builtin_interfaces/Time's range")
    return Stamp(sec, nanosec)


class FrameIds:
    """The ``header.frame_id`` of recently sent images by stamp, so a score gets the
    frame of the image it scored. Bounded: the oldest are forgotten first; a stamp not
    remembered gets the latest frame id."""

    def __init__(self, capacity: int = 256) -> None:
        self._capacity = capacity
        self._by_stamp: dict[int, str] = {}
        self.latest = ""

    def remember(self, stamp: int, frame_id: str) -> None:
        self.latest = frame_id
        self._by_stamp[stamp] = frame_id
        while len(self._by_stamp) > self._capacity:
            del self._by_stamp[next(iter(self._by_stamp))]

    def pop(self, stamp: int) -> str:
        return self._by_stamp.pop(stamp, self.latest)

    def __len__(self) -> int:
        return len(self._by_stamp)


def _nan_if_none(x: Optional[float]) -> float:
    return math.nan if x is None else float(x)


def frame_score_fields(score: FrameScore, frame_id: str, session_id: str) -> dict[str, Any]:
    """The fields of a ``vamos_msgs/FrameScore`` (msg/FrameScore.msg) for ``score``:
    ``header`` as ``(Stamp, frame_id)``, errors not computed as NaN, the detector's name
    or ``""``."""
    return {
        "header": (stamp_from_ns(score.stamp_ns), frame_id),
        "score": float(score.score),
        "anomaly": bool(score.anomaly),
        "detector": score.detector or "",
        "e_c": _nan_if_none(score.e_c),
        "e_b": _nan_if_none(score.e_b),
        "e_o": _nan_if_none(score.e_o),
        "e_r": _nan_if_none(score.e_r),
        "e_k": _nan_if_none(score.e_k),
        "warming_up": bool(score.warming_up),
        "frame": int(score.frame),
        "latency_s": float(score.latency_s),
        "session_id": session_id,
    }


#: ``vamos_msgs/AlarmEvent`` edge constants (msg/AlarmEvent.msg).
ALARM_STARTED, ALARM_ENDED = 1, 2


def _alarm_frame_fields(c: AlarmComponents) -> dict[str, Any]:
    """The fields of a ``vamos_msgs/AlarmFrame``: ``stamp`` as a :class:`Stamp`, values
    not defined as NaN."""
    return {
        "stamp": stamp_from_ns(c.stamp_ns),
        "score": _nan_if_none(c.score),
        "e_c": _nan_if_none(c.e_c),
        "e_b": _nan_if_none(c.e_b),
        "e_o": _nan_if_none(c.e_o),
        "e_r": _nan_if_none(c.e_r),
        "e_k": _nan_if_none(c.e_k),
    }


def alarm_event_fields(alarm: AlarmEvent, frame_id: str, robot_id: str) -> dict[str, Any]:
    """The fields of a ``vamos_msgs/AlarmEvent`` (msg/AlarmEvent.msg) for ``alarm`` of
    robot ``robot_id``: ``header`` as ``(Stamp, frame_id)`` with the stamp of the image at
    which it started or ended, ``start`` and ``peak`` as the fields of an ``AlarmFrame``,
    thresholds and values not defined as NaN, ``end_frame`` 0 while it is on.
    :class:`ValueError` for an edge that is neither a start nor an end, or a stamp
    outside ``builtin_interfaces/Time``."""
    if not (alarm.started or alarm.ended):
        raise ValueError(f"alarm {alarm.alarm_id}: edge {alarm.edge!r} is neither a start nor an end")
    t = alarm.thresholds
    return {
        "header": (stamp_from_ns(alarm.stamp_ns), frame_id),
        "edge": ALARM_STARTED if alarm.started else ALARM_ENDED,
        "alarm_id": alarm.alarm_id,
        "session_id": alarm.session_id,
        "robot_id": robot_id,
        "detector": alarm.detector or "",
        "detectors": list(alarm.detectors),
        "start_frame": int(alarm.start_frame),
        "end_frame": int(alarm.end_frame or 0),
        "frames_flagged": int(alarm.frames_flagged),
        "alarm_threshold": _nan_if_none(t.alarm),
        "e_c_threshold": _nan_if_none(t.e_c),
        "e_b_threshold": _nan_if_none(t.e_b),
        "e_o_threshold": _nan_if_none(t.e_o),
        "e_r_threshold": _nan_if_none(t.e_r),
        "e_k_threshold": _nan_if_none(t.e_k),
        "start": _alarm_frame_fields(alarm.start),
        "peak": _alarm_frame_fields(alarm.peak),
    }


def anomaly_map_fields(score: FrameScore, frame_id: str) -> Optional[dict[str, Any]]:
    """The fields of a ``sensor_msgs/Image`` (``mono8``, packed rows, 0 = nominal) of the
    anomaly map ``score`` carries, with its image's header; None when it has none.
    :class:`ValueError` when the map is not the server's 8-bit gray PNG."""
    m = score.anomaly_map_image()
    if m is None:
        return None
    return {
        "header": (stamp_from_ns(score.stamp_ns), frame_id),
        "height": m.height,
        "width": m.width,
        "encoding": "mono8",
        "is_bigendian": 0,
        "step": m.width,
        "data": bytes(m.pixels),
    }
