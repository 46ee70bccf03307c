"""Conversions from Python values (numpy arrays, encoded bytes, ROS 2 messages) to the
``vamos.v1`` request messages."""

from __future__ import annotations

import math
from typing import Any, Optional, Sequence

from vamos.v1 import monitor_pb2 as pb

_PNG = b"\x89PNG\r\n\x1a\n"
_JPEG = b"\xff\xd8\xff"


def encoded_format(data: bytes) -> Optional[str]:
    """``"png"`` or ``"jpeg"`` from the leading bytes, else None."""
    if data.startswith(_PNG):
        return "png"
    if data.startswith(_JPEG):
        return "jpeg"
    return None


def image_message(image: Any, stamp_ns: int, encoding: Optional[str] = None, depth: Any = None) -> Any:
    """A ``vamos.v1.Image`` from a numpy array or encoded bytes, with ``depth`` (see
    :func:`depth_message`) when given.

    Arrays: ``HxW`` uint8 (``mono8``), ``HxW`` uint16 (``mono16``), ``HxW`` float32
    (``32FC1``), ``HxWx3`` uint8 (``rgb8``, or ``bgr8`` when ``encoding`` says so),
    ``HxWx4`` uint8 (``rgba8``/``bgra8``). Bytes: JPEG or PNG (the format is detected;
    ``encoding`` may name it). A ``vamos.v1.Image`` is passed through with its stamp set.
    """
    out = _image_message(image, stamp_ns, encoding)
    if depth is not None:
        out.depth.CopyFrom(depth_message(depth))
    return out


def _image_message(image: Any, stamp_ns: int, encoding: Optional[str] = None) -> Any:
    stamp_ns = int(stamp_ns)
    if isinstance(image, pb.Image):
        out = pb.Image()
        out.CopyFrom(image)
        out.stamp_ns = stamp_ns
        return out
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        fmt = encoding.lower() if encoding else encoded_format(data)
        if fmt == "jpg":
            fmt = "jpeg"
        if fmt not in ("jpeg", "png"):
            raise ValueError("bytes must be a JPEG or PNG image (pass a numpy array for raw pixels)")
        return pb.Image(stamp_ns=stamp_ns, encoding=fmt, data=data)
    import numpy as np

    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 2:
        by_dtype = {np.dtype(np.uint8): "mono8", np.dtype(np.uint16): "mono16",
                    np.dtype(np.float32): "32FC1"}
        enc = by_dtype.get(a.dtype)
        if enc is None:
            raise ValueError(f"a single-channel image must be uint8, uint16 or float32, got {a.dtype}")
    elif a.ndim == 3 and a.shape[2] in (3, 4):
        if a.dtype != np.uint8:
            raise ValueError(f"a colour image must be uint8, got {a.dtype}")
        default = "rgb8" if a.shape[2] == 3 else "rgba8"
        enc = (encoding or default).lower()
        allowed = ("rgb8", "bgr8") if a.shape[2] == 3 else ("rgba8", "bgra8")
        if enc not in allowed:
            raise ValueError(f"encoding {enc!r} does not fit a {a.shape[2]}-channel image: use {allowed}")
    else:
        raise ValueError(f"an image must be HxW or HxWx3/4, got shape {a.shape}")
    h, w = a.shape[:2]
    if h == 0 or w == 0:
        raise ValueError("empty image")
    little = a.dtype.byteorder in ("<", "=", "|")
    a = np.ascontiguousarray(a)
    return pb.Image(stamp_ns=stamp_ns, encoding=enc, width=w, height=h,
                    step=a.strides[0], big_endian=not little and a.itemsize > 1, data=a.tobytes())


def depth_message(depth: Any) -> Any:
    """A ``vamos.v1.DepthImage`` from an ``HxW`` numpy array registered to its image (the
    same field of view, any resolution of the same aspect ratio): float32 metres
    (``32FC1``) or uint16 millimetres (``16UC1``); 0 and NaN mean no depth. A
    ``vamos.v1.DepthImage`` is passed through."""
    if isinstance(depth, pb.DepthImage):
        return depth
    import numpy as np

    a = np.asarray(depth)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    by_dtype = {np.dtype(np.float32): "32FC1", np.dtype(np.uint16): "16UC1"}
    if a.ndim != 2 or a.dtype.newbyteorder("=") not in by_dtype:
        raise ValueError(f"a depth image must be HxW float32 metres or uint16 millimetres, got "
                         f"{a.dtype} of shape {a.shape}")
    h, w = a.shape
    if h == 0 or w == 0:
        raise ValueError("empty depth image")
    big = a.dtype.byteorder == ">"
    a = np.ascontiguousarray(a)
    return pb.DepthImage(encoding=by_dtype[a.dtype.newbyteorder("=")], width=w, height=h,
                         step=a.strides[0], big_endian=big, data=a.tobytes())


def joint_message(names: Sequence[str], positions: Sequence[float], stamp_ns: int,
                  velocities: Sequence[float] = (), efforts: Sequence[float] = ()) -> Any:
    """A ``vamos.v1.JointState``; refuses mismatched lengths and non-finite positions
    here, before they reach the server."""
    names = [str(n) for n in names]
    positions = [float(p) for p in positions]
    if len(names) != len(positions):
        raise ValueError(f"{len(names)} joint names but {len(positions)} positions")
    bad = [n for n, p in zip(names, positions) if not math.isfinite(p)]
    if bad:
        raise ValueError(f"non-finite positions for joints {bad}")
    return pb.JointState(stamp_ns=int(stamp_ns), names=names, positions=positions,
                         velocities=[float(v) for v in velocities],
                         efforts=[float(e) for e in efforts])


def ros_stamp_ns(msg: Any) -> int:
    """``header.stamp`` of a decoded ROS 2 message, nanoseconds."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ros_image(msg: Any) -> Any:
    """A ``vamos.v1.Image`` from a decoded ``sensor_msgs/msg/Image``."""
    return pb.Image(stamp_ns=ros_stamp_ns(msg), encoding=str(msg.encoding), width=int(msg.width),
                    height=int(msg.height), step=int(msg.step), big_endian=bool(msg.is_bigendian),
                    data=bytes(msg.data))


def ros_depth(msg: Any) -> Any:
    """A ``vamos.v1.DepthImage`` from a decoded ``sensor_msgs/msg/Image`` (16UC1 or 32FC1;
    the server says when it cannot use another)."""
    return pb.DepthImage(encoding=str(msg.encoding), width=int(msg.width), height=int(msg.height),
                         step=int(msg.step), big_endian=bool(msg.is_bigendian), data=bytes(msg.data))


def ros_compressed_image(msg: Any) -> Any:
    """A ``vamos.v1.Image`` from a decoded ``sensor_msgs/msg/CompressedImage``."""
    data = bytes(msg.data)
    fmt = encoded_format(data)
    if fmt is None:
        text = str(msg.format).lower()
        fmt = "png" if "png" in text else "jpeg" if ("jpeg" in text or "jpg" in text) else None
    if fmt is None:
        raise ValueError(f"compressed image format {msg.format!r} is neither JPEG nor PNG")
    return pb.Image(stamp_ns=ros_stamp_ns(msg), encoding=fmt, data=data)


def ros_joint_state(msg: Any) -> Any:
    """A ``vamos.v1.JointState`` from a decoded ``sensor_msgs/msg/JointState`` (not
    validated: the server reports bad samples as events, as it would for a robot)."""
    return pb.JointState(stamp_ns=ros_stamp_ns(msg), names=list(msg.name),
                         positions=list(msg.position), velocities=list(msg.velocity),
                         efforts=list(msg.effort))
