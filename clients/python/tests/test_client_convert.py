"""Conversions and parsing of the client, without a server."""

from __future__ import annotations

import zlib

import pytest

np = pytest.importorskip("numpy")
pytest.importorskip("grpc")

from vamos.client import CameraInfo, FrameScore, SessionEvent  # noqa: E402
from vamos.client._convert import depth_message, image_message, joint_message  # noqa: E402
from vamos.client.monitor import channel_target  # noqa: E402
from vamos.v1 import monitor_pb2 as pb  # noqa: E402


def _png(width: int, height: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (len(data).to_bytes(4, "big") + kind + data
                + zlib.crc32(kind + data).to_bytes(4, "big"))
    raw = b"".join(b"\x00" + bytes(width) for _ in range(height))
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
            + chunk(b"IEND", b""))


def test_arrays_become_raw_images_with_their_encoding() -> None:
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4)
    m = image_message(gray, 5)
    assert (m.encoding, m.width, m.height, m.step, m.stamp_ns) == ("mono8", 4, 3, 4, 5)
    assert m.data == gray.tobytes()
    rgb = np.zeros((2, 3, 3), dtype=np.uint8)
    rgb[1, 2] = (1, 2, 3)
    m = image_message(rgb, 7)
    assert (m.encoding, m.step) == ("rgb8", 9)
    assert m.data[-3:] == b"\x01\x02\x03"
    assert image_message(rgb, 7, "bgr8").encoding == "bgr8"
    m = image_message(np.full((2, 2), 1000, dtype=np.uint16), 1)
    assert (m.encoding, m.step, m.big_endian) == ("mono16", 4, False)
    assert m.data == np.full((2, 2), 1000, dtype="<u2").tobytes()
    assert image_message(np.zeros((2, 2), np.float32), 1).encoding == "32FC1"
    # A non-contiguous view is packed.
    view = np.arange(24, dtype=np.uint8).reshape(4, 6)[:, ::2]
    m = image_message(view, 1)
    assert m.step == 3 and m.data == np.ascontiguousarray(view).tobytes()
    assert image_message(np.zeros((2, 2, 4), np.uint8), 1).encoding == "rgba8"


def test_depth_arrays_ride_with_their_image() -> None:
    rgb = np.zeros((4, 6, 3), dtype=np.uint8)
    metres = np.full((2, 3), 1.25, dtype=np.float32)
    m = image_message(rgb, 9, depth=metres)
    assert m.HasField("depth") and (m.depth.encoding, m.depth.width, m.depth.height) == ("32FC1", 3, 2)
    assert (m.depth.step, m.depth.big_endian, m.depth.data) == (12, False, metres.tobytes())
    mm = np.array([[1000, 0], [2500, 65535]], dtype=">u2")
    d = depth_message(mm)
    assert (d.encoding, d.step, d.big_endian, d.data) == ("16UC1", 4, True, mm.tobytes())
    assert not image_message(rgb, 9).HasField("depth")
    with pytest.raises(ValueError, match="float32 metres or uint16 millimetres"):
        depth_message(np.zeros((2, 2), np.float64))
    with pytest.raises(ValueError, match="float32 metres or uint16 millimetres"):
        depth_message(np.zeros((2, 2, 3), np.float32))
    with pytest.raises(ValueError, match="empty"):
        depth_message(np.zeros((0, 2), np.uint16))


def test_encoded_bytes_are_detected_and_bad_images_refused() -> None:
    png = _png(4, 2)
    assert image_message(png, 3).encoding == "png"
    assert image_message(b"\xff\xd8\xff\xe0rest", 3).encoding == "jpeg"
    with pytest.raises(ValueError, match="JPEG or PNG"):
        image_message(b"not an image", 3)
    with pytest.raises(ValueError, match="uint8"):
        image_message(np.zeros((2, 2, 3), np.float64), 1)
    with pytest.raises(ValueError, match="single-channel"):
        image_message(np.zeros((2, 2), np.int64), 1)
    with pytest.raises(ValueError, match="shape"):
        image_message(np.zeros((2, 2, 2, 2), np.uint8), 1)
    with pytest.raises(ValueError, match="does not fit"):
        image_message(np.zeros((2, 2, 3), np.uint8), 1, "rgba8")
    with pytest.raises(ValueError, match="empty"):
        image_message(np.zeros((0, 2), np.uint8), 1)


def test_joint_states_are_checked_before_sending() -> None:
    m = joint_message(["a", "b"], [0.5, -1], 9, velocities=[1, 2])
    assert list(m.names) == ["a", "b"] and list(m.positions) == [0.5, -1.0]
    assert list(m.velocities) == [1.0, 2.0] and m.stamp_ns == 9
    with pytest.raises(ValueError, match="2 joint names but 1"):
        joint_message(["a", "b"], [0.5], 1)
    with pytest.raises(ValueError, match="non-finite"):
        joint_message(["a"], [float("nan")], 1)


def test_scores_and_events_from_the_wire() -> None:
    m = pb.FrameScore(stamp_ns=10, index=3, frame=2, score=1.5, e_c=0.25, anomaly=True,
                      detector=pb.DETECTOR_CAMERA, warming_up=True, latency_s=0.01)
    s = FrameScore.from_proto(m)
    assert (s.e_c, s.e_b, s.e_o, s.detector, s.anomaly) == (0.25, None, None, "camera", True)
    assert s.to_dict()["latency_s"] == 0.01
    e = SessionEvent.from_proto(pb.SessionEvent(kind=pb.SessionEvent.KIND_FRAMES_DROPPED,
                                                session_id="x", detail="d", count=4))
    assert (e.kind, e.count) == ("frames_dropped", 4)
    c = CameraInfo.from_k(640, 480, [500, 0, 320, 0, 510, 240, 0, 0, 1])
    assert (c.fx, c.fy, c.cx, c.cy) == (500, 510, 320, 240)
    with pytest.raises(ValueError):
        CameraInfo.from_k(1, 1, [1, 2])


def test_server_addresses() -> None:
    assert channel_target("127.0.0.1:8081") == ("127.0.0.1:8081", False)
    assert channel_target("http://h:1/") == ("h:1", False)
    assert channel_target("https://h:1") == ("h:1", True)
