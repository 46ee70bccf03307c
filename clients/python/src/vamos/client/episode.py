"""Recorded episodes (ROS 2 bags in MCAP) as the messages a robot would stream.

Needs the ``mcap`` and ``mcap-ros2-support`` packages (dependencies of the package:
``pip install vamos-client`` brings them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from vamos.v1 import monitor_pb2 as pb

from . import _convert
from ._types import CameraInfo, VamosError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
JOINTS = "sensor_msgs/msg/JointState"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


@dataclass
class Recording:
    """An episode's stream: ``(offset_ns, StreamRequest)`` in log-time order (offsets
    from the first message), and the first camera info."""

    messages: list[tuple[int, Any]] = field(default_factory=list)
    camera: Optional[CameraInfo] = None
    image_topic: str = ""
    joint_topics: list[str] = field(default_factory=list)

    @property
    def images(self) -> int:
        return sum(1 for _, m in self.messages if m.WhichOneof("message") == "image")


#: A depth image is attached to the image nearest its stamp within this (as vamos's
#: ``[episode] max_depth_gap_ms`` default).
MAX_DEPTH_GAP_NS = 20_000_000


def _pick(kind: str, topics: dict[str, str], wanted: Optional[str], schemas: tuple[str, ...]) -> Optional[str]:
    found = sorted(t for t, s in topics.items() if s in schemas)
    if wanted is not None:
        if wanted not in topics:
            raise VamosError(f"no {kind} topic {wanted!r} in the bag; it has {sorted(topics)}")
        return wanted
    if kind == "image" and len(found) > 1:
        # As vamos reads bags: a depth camera's topic is not the image.
        colour = [t for t in found if "depth" not in t]
        if len(colour) == 1:
            return colour[0]
    if len(found) > 1:
        raise VamosError(f"several {kind} topics {found}: choose one")
    return found[0] if found else None


def read_episode(path: "str | Path", image_topic: Optional[str] = None,
                 joint_topics: Optional[list[str]] = None,
                 camera_info_topic: Optional[str] = None,
                 depth_topic: Optional[str] = None) -> Recording:
    """Reads an MCAP episode into a :class:`Recording`. Topics are found by message type
    when there is one of a kind (joint states: every JointState topic; images: the one
    not named ``*depth*`` when there are several), else name them. ``depth_topic``: depth
    images registered to the images (16UC1 or 32FC1 ``sensor_msgs/msg/Image``), each
    attached to the image nearest its stamp within 20 ms."""
    try:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise VamosError("reading MCAP episodes needs mcap and mcap-ros2-support, dependencies of the "
                         f"package (`pip install vamos-client`): {e}") from e
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            topics: dict[str, str] = {}
            if summary is not None:
                for ch in summary.channels.values():
                    schema = summary.schemas.get(ch.schema_id)
                    topics[ch.topic] = schema.name if schema is not None else ""
            image = _pick("image", topics, image_topic, (IMAGE, COMPRESSED))
            if image is None:
                raise VamosError(f"{path}: no sensor_msgs Image or CompressedImage topic")
            joints = joint_topics if joint_topics is not None else sorted(
                t for t, s in topics.items() if s == JOINTS)
            info = _pick("camera info", topics, camera_info_topic, (CAMERA_INFO,))
            depth = _pick("depth", topics, depth_topic, (IMAGE,)) if depth_topic else None
            if depth == image:
                raise VamosError(f"{path}: the depth topic {depth!r} is the image topic")
            depths: list[tuple[int, Any]] = []
            wanted = {image, *joints} | ({info} if info else set()) | ({depth} if depth else set())
            rec = Recording(image_topic=image, joint_topics=list(joints))
            first: Optional[int] = None
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                    topics=sorted(wanted), log_time_order=True):
                if first is None:
                    first = int(message.log_time)
                offset = int(message.log_time) - first
                if channel.topic == info:
                    if rec.camera is None:
                        rec.camera = CameraInfo.from_k(decoded.width, decoded.height, decoded.k)
                    continue
                if channel.topic == depth:
                    depths.append((_convert.ros_stamp_ns(decoded), _convert.ros_depth(decoded)))
                elif channel.topic == image:
                    img = (_convert.ros_compressed_image(decoded) if schema.name == COMPRESSED
                           else _convert.ros_image(decoded))
                    rec.messages.append((offset, pb.StreamRequest(image=img)))
                elif channel.topic in joints:
                    rec.messages.append((offset, pb.StreamRequest(joints=_convert.ros_joint_state(decoded))))
    except VamosError:
        raise
    except Exception as e:  # the mcap reader's errors have no common base
        raise VamosError(f"{path}: not a readable MCAP episode: {e}") from e
    _attach_depths(rec, depths)
    return rec


def _attach_depths(rec: Recording, depths: list[tuple[int, Any]]) -> None:
    """Gives each image the unused depth image nearest its stamp within
    :data:`MAX_DEPTH_GAP_NS`."""
    if not depths:
        return
    import bisect

    depths.sort(key=lambda d: d[0])
    stamps = [t for t, _ in depths]
    used = [False] * len(depths)
    for _, m in rec.messages:
        if m.WhichOneof("message") != "image":
            continue
        t = m.image.stamp_ns
        at = bisect.bisect_left(stamps, t)
        near = [i for i in (at - 1, at) if 0 <= i < len(stamps) and not used[i]
                and abs(stamps[i] - t) <= MAX_DEPTH_GAP_NS]
        if near:
            i = min(near, key=lambda i: abs(stamps[i] - t))
            used[i] = True
            m.image.depth.CopyFrom(depths[i][1])
