"""ROS 2 bag writing (MCAP, CDR, zstd chunks) for the simulator's topics."""

from __future__ import annotations

from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType
from mcap_ros2.writer import Writer

IMAGE_TOPIC = "/camera/image_raw"
CAMERA_INFO_TOPIC = "/camera/camera_info"
#: Depth images registered to the images (``vamos-sim generate --depth``): 16UC1, millimetres.
DEPTH_TOPIC = "/camera/depth/image_raw"
JOINT_STATES_TOPIC = "/joint_states"
ROBOT_DESCRIPTION_TOPIC = "/robot_description"

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_SEP = "=" * 80 + "\n"


def _with_deps(main: str, *deps: tuple[str, str]) -> str:
    return main + "".join(f"{_SEP}MSG: {name}\n{text}" for name, text in deps)


_IMAGE = _with_deps(
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    "uint32 step\nuint8[] data\n",
    ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))
_CAMERA_INFO = _with_deps(
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
    "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
    "sensor_msgs/RegionOfInterest roi\n",
    ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME),
    ("sensor_msgs/RegionOfInterest", "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\n"
                                     "bool do_rectify\n"))
_JOINT_STATE = _with_deps(
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
    ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))
_STRING = "string data\n"


def _stamp(t_ns: int) -> dict[str, int]:
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


class BagWriter:
    """Writes the simulator's topics to one MCAP file (zstd-compressed chunks)."""

    def __init__(self, path: Path) -> None:
        self._file: IO[bytes] = open(path, "wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._image = self._writer.register_msgdef("sensor_msgs/msg/Image", _IMAGE)
        self._info = self._writer.register_msgdef("sensor_msgs/msg/CameraInfo", _CAMERA_INFO)
        self._joints = self._writer.register_msgdef("sensor_msgs/msg/JointState", _JOINT_STATE)
        self._string = self._writer.register_msgdef("std_msgs/msg/String", _STRING)

    def _write(self, topic: str, schema: Any, msg: dict[str, Any], t_ns: int) -> None:
        self._writer.write_message(topic, schema, msg, log_time=t_ns, publish_time=t_ns)

    def robot_description(self, t_ns: int, urdf: str) -> None:
        """The URDF text on ``/robot_description``."""
        self._write(ROBOT_DESCRIPTION_TOPIC, self._string, {"data": urdf}, t_ns)

    def image(self, t_ns: int, frame_id: str, rgb: bytes, width: int, height: int) -> None:
        """An rgb8 image."""
        self._write(IMAGE_TOPIC, self._image, {
            "header": {"stamp": _stamp(t_ns), "frame_id": frame_id}, "height": height, "width": width,
            "encoding": "rgb8", "is_bigendian": 0, "step": 3 * width, "data": rgb}, t_ns)

    def depth(self, t_ns: int, frame_id: str, millimetres: bytes, width: int, height: int) -> None:
        """A 16UC1 depth image (millimetres along the optical axis, 0 = none; REP 118),
        registered to the image of the same stamp."""
        self._write(DEPTH_TOPIC, self._image, {
            "header": {"stamp": _stamp(t_ns), "frame_id": frame_id}, "height": height, "width": width,
            "encoding": "16UC1", "is_bigendian": 0, "step": 2 * width, "data": millimetres}, t_ns)

    def camera_info(self, t_ns: int, frame_id: str, width: int, height: int,
                    fx: float, fy: float, cx: float, cy: float) -> None:
        """Pinhole camera info (plumb_bob, zero distortion)."""
        self._write(CAMERA_INFO_TOPIC, self._info, {
            "header": {"stamp": _stamp(t_ns), "frame_id": frame_id}, "height": height, "width": width,
            "distortion_model": "plumb_bob", "d": [0.0] * 5,
            "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}, t_ns)

    def joint_state(self, t_ns: int, names: list[str], position: list[float], velocity: list[float],
                    effort: list[float]) -> None:
        """A joint state message."""
        self._write(JOINT_STATES_TOPIC, self._joints, {
            "header": {"stamp": _stamp(t_ns), "frame_id": ""}, "name": names, "position": position,
            "velocity": velocity, "effort": effort}, t_ns)

    def close(self) -> None:
        """Finishes the file (summary, index) and closes it."""
        self._writer.finish()
        self._file.close()
