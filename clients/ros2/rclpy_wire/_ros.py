"""What the rclpy tests share: rclpy on Fast DDS in a domain of its own, and a recorded
episode as rclpy messages."""

from __future__ import annotations

import os
import random
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pytest

ROOT = Path(__file__).resolve().parents[3]
EPISODE = ROOT / "tests" / "fixtures" / "sim" / "test" / "test_0000.mcap"


@contextmanager
def ros_context() -> Iterator[tuple[Any, Any, int]]:
    """``(rclpy, context, domain)``: rclpy on Fast DDS in a domain of its own (parallel
    runs on one host do not meet); skips the test without rclpy."""
    os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    rclpy = pytest.importorskip("rclpy")
    domain = random.randint(100, 200)
    context = rclpy.context.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        yield rclpy, context, domain
    finally:
        rclpy.shutdown(context=context)


def read_episode(path: Path) -> list[tuple[str, Any]]:
    """The bag's camera, camera info and joint state messages in log-time order, as rclpy
    messages."""
    from builtin_interfaces.msg import Time
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from sensor_msgs.msg import CameraInfo, Image, JointState, RegionOfInterest
    from std_msgs.msg import Header

    def header(m: Any) -> Header:
        return Header(stamp=Time(sec=m.header.stamp.sec, nanosec=m.header.stamp.nanosec),
                      frame_id=m.header.frame_id)

    out: list[tuple[str, Any]] = []
    with path.open("rb") as f:
        for _s, channel, _m, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/camera/image_raw":
                out.append(("image", Image(header=header(m), height=m.height, width=m.width, encoding=m.encoding,
                                           is_bigendian=m.is_bigendian, step=m.step, data=bytes(m.data))))
            elif channel.topic == "/camera/camera_info":
                roi = RegionOfInterest(x_offset=m.roi.x_offset, y_offset=m.roi.y_offset, height=m.roi.height,
                                       width=m.roi.width, do_rectify=m.roi.do_rectify)
                out.append(("camera_info", CameraInfo(
                    header=header(m), height=m.height, width=m.width, distortion_model=m.distortion_model,
                    d=list(m.d), k=list(m.k), r=list(m.r), p=list(m.p), binning_x=m.binning_x,
                    binning_y=m.binning_y, roi=roi)))
            elif channel.topic == "/joint_states":
                out.append(("joints", JointState(header=header(m), name=list(m.name), position=list(m.position),
                                                 velocity=list(m.velocity), effort=list(m.effort))))
    return out


def stamp_ns(stamp: Any) -> int:
    """A ``builtin_interfaces/Time`` in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
