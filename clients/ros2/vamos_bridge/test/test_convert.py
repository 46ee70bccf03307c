"""Messages to requests and scores to FrameScore fields, with stand-in messages that
have the fields of sensor_msgs (no ROS here)."""

from __future__ import annotations

import math
import re
from pathlib import Path
from types import SimpleNamespace as NS

import pytest

from vamos.client import AlarmComponents, AlarmEvent, AlarmThresholds, FrameScore
from vamos_bridge.convert import (
    ALARM_ENDED,
    ALARM_STARTED,
    FrameIds,
    Stamp,
    alarm_event_fields,
    anomaly_map_fields,
    camera_info,
    depth_image,
    frame_score_fields,
    image_request,
    joints_request,
    stamp_from_ns,
    stamp_ns,
    with_depth,
)

MSGS = Path(__file__).resolve().parents[2] / "vamos_msgs" / "msg"
MSG = MSGS / "FrameScore.msg"


def header(sec: int, nanosec: int, frame_id: str = "camera") -> NS:
    return NS(stamp=NS(sec=sec, nanosec=nanosec), frame_id=frame_id)


def test_ros_messages_become_stream_requests() -> None:
    raw = NS(header=header(3, 500), height=2, width=3, encoding="rgb8", is_bigendian=0, step=9,
             data=bytes(range(18)))
    r = image_request(raw)
    assert r.WhichOneof("message") == "image"
    assert (r.image.stamp_ns, r.image.encoding, r.image.width, r.image.height, r.image.step) == (
        3_000_000_500, "rgb8", 3, 2, 9)
    assert r.image.data == bytes(range(18))
    jpeg = NS(header=header(1, 0), format="rgb8; jpeg compressed bgr8", data=b"\xff\xd8\xff\xe0xx")
    assert image_request(jpeg).image.encoding == "jpeg"
    png = NS(header=header(1, 0), format="png", data=b"garbage")
    assert image_request(png).image.encoding == "png"
    with pytest.raises(ValueError, match="neither JPEG nor PNG"):
        image_request(NS(header=header(1, 0), format="theora", data=b"x"))
    j = joints_request(NS(header=header(2, 7), name=["a", "b"], position=[0.1, 0.2], velocity=[],
                          effort=[1.0, 2.0]))
    assert (j.joints.stamp_ns, list(j.joints.names), list(j.joints.efforts)) == (2_000_000_007, ["a", "b"], [1.0, 2.0])
    c = camera_info(NS(width=640, height=480, k=[500.0, 0, 320, 0, 505, 240, 0, 0, 1]))
    assert (c.fx, c.fy, c.cx, c.cy, c.width) == (500.0, 505.0, 320.0, 240.0, 640)
    with pytest.raises(ValueError, match="uncalibrated"):
        camera_info(NS(width=640, height=480, k=[0.0] * 9))
    with pytest.raises(ValueError, match="non-finite"):
        camera_info(NS(width=640, height=480, k=[500.0, 0, float("nan"), 0, 505, 240, 0, 0, 1]))
    with pytest.raises(ValueError, match="size"):
        camera_info(NS(width=0, height=0, k=[500.0, 0, 320, 0, 505, 240, 0, 0, 1]))
    with pytest.raises(ValueError, match="expected 9"):
        camera_info(NS(width=640, height=480, k=[1.0] * 4))


def test_a_depth_image_rides_with_its_image_as_it_came() -> None:
    import numpy as np

    mm = np.array([[500, 0, 1200], [65535, 7, 800]], dtype=">u2")  # big-endian rows
    depth = NS(header=header(3, 400, "depth_optical"), height=2, width=3, encoding="16UC1", is_bigendian=1,
               step=6, data=mm.tobytes())
    d = depth_image(depth)
    assert (d.encoding, d.width, d.height, d.step, d.big_endian, d.data) == ("16UC1", 3, 2, 6, True, mm.tobytes())
    assert stamp_ns(depth) == 3_000_000_400
    metres = np.full((2, 3), 1.5, dtype=np.float32)
    f = depth_image(NS(header=header(3, 0), height=2, width=3, encoding="32FC1", is_bigendian=0, step=12,
                       data=metres.tobytes()))
    assert (f.encoding, f.step, f.big_endian) == ("32FC1", 12, False)
    assert np.array_equal(np.frombuffer(f.data, np.float32).reshape(2, 3), metres)
    # Another encoding is not refused here: the server says why it cannot use it.
    assert depth_image(NS(header=header(1, 0), height=1, width=1, encoding="rgb8", is_bigendian=0, step=3,
                          data=b"abc")).encoding == "rgb8"
    # The image's request carries it, or nothing.
    raw = NS(header=header(3, 500), height=2, width=3, encoding="rgb8", is_bigendian=0, step=9,
             data=bytes(range(18)))
    r = with_depth(image_request(raw), d)
    assert r.image.depth == d and r.image.stamp_ns == 3_000_000_500
    assert not with_depth(image_request(raw), None).image.HasField("depth")


@pytest.mark.parametrize("ns,sec,nanosec", [
    (0, 0, 0),
    (1_704_067_200_123_456_789, 1_704_067_200, 123_456_789),
    (999_999_999, 0, 999_999_999),
    (-1, -1, 999_999_999),            # before 1970: nanosec stays in [0, 1e9)
    (-1_500_000_000, -2, 500_000_000),
    ((2**31 - 1) * 10**9 + 999_999_999, 2**31 - 1, 999_999_999),
])
def test_stamps_round_trip_exactly(ns: int, sec: int, nanosec: int) -> None:
    assert stamp_from_ns(ns) == Stamp(sec, nanosec)
    assert stamp_ns(NS(header=header(sec, nanosec))) == ns


def test_stamps_outside_int32_seconds_are_refused() -> None:
    with pytest.raises(ValueError, match="outside"):
        stamp_from_ns(2**31 * 10**9)
    with pytest.raises(ValueError, match="outside"):
        stamp_from_ns(-(2**31) * 10**9 - 1)


def test_frame_ids_follow_their_images_and_stay_bounded() -> None:
    ids = FrameIds(capacity=3)
    assert ids.pop(5) == ""
    for stamp, frame in ((1, "cam_a"), (2, "cam_b"), (3, "cam_c"), (4, "cam_d")):
        ids.remember(stamp, frame)
    assert len(ids) == 3
    assert ids.pop(2) == "cam_b" and len(ids) == 2
    assert ids.pop(1) == "cam_d"  # forgotten (oldest): the latest frame id
    assert ids.pop(99) == "cam_d"


def msg_fields() -> dict[str, str]:
    fields = {}
    for line in MSG.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            kind, name = line.split()
            fields[name] = kind
    return fields


def test_frame_score_fields_are_the_message_definition() -> None:
    fields = msg_fields()
    assert all(re.fullmatch(r"[a-z][a-z0-9_]*", name) for name in fields)
    score = FrameScore(stamp_ns=1_704_067_200_000_000_042, index=7, frame=9, score=3.5, e_c=1.25, e_b=None,
                       e_o=0.5, anomaly=True, detector="camera", warming_up=False, e_r=None, latency_s=0.03)
    got = frame_score_fields(score, "head_camera_optical", "arm-1-abc")
    assert list(got) == list(fields)
    python_type = {"float64": float, "bool": bool, "string": str, "uint64": int}
    for name, kind in fields.items():
        if kind == "std_msgs/Header":
            assert got[name] == (Stamp(1_704_067_200, 42), "head_camera_optical")
        else:
            assert type(got[name]) is python_type[kind], name
    assert (got["score"], got["anomaly"], got["detector"], got["e_c"], got["e_o"]) == (3.5, True, "camera", 1.25, 0.5)
    assert math.isnan(got["e_b"]) and math.isnan(got["e_r"])
    assert (got["frame"], got["latency_s"], got["session_id"], got["warming_up"]) == (9, 0.03, "arm-1-abc", False)
    quiet = FrameScore(stamp_ns=0, index=0, frame=0, score=0.0, e_c=None, e_b=None, e_o=None, anomaly=False,
                       detector=None, warming_up=True)
    assert frame_score_fields(quiet, "", "s")["detector"] == ""


def definition(name: str) -> tuple[dict[str, str], dict[str, int]]:
    """``(fields, constants)`` of ``vamos_msgs/msg/<name>.msg``: field name -> type, in order."""
    fields: dict[str, str] = {}
    constants: dict[str, int] = {}
    for line in (MSGS / f"{name}.msg").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        kind, rest = line.split(maxsplit=1)
        if "=" in rest:
            key, value = (x.strip() for x in rest.split("=", 1))
            constants[key] = int(value)
        else:
            fields[rest] = kind
    return fields, constants


def gray_png(width: int, height: int, pixels: bytes) -> bytes:
    """An 8-bit gray PNG of ``pixels`` (filter 0 on every row)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + pixels[y * width:(y + 1) * width] for y in range(height))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def an_alarm(edge: str = "started") -> AlarmEvent:
    return AlarmEvent(
        edge=edge, alarm_id="a7", session_id="arm-1-abc", detector="flow", detectors=("flow", "scene"),
        start_frame=12, end_frame=20 if edge == "ended" else None,
        end_stamp_ns=3_000_000_007 if edge == "ended" else None, frames_flagged=5,
        thresholds=AlarmThresholds(alarm=1.0, e_o=1.0, e_r=2.5),
        start=AlarmComponents(stamp_ns=1_200_000_001, score=1.5, e_c=0.2, e_o=1.5),
        peak=AlarmComponents(stamp_ns=1_500_000_000, score=4.0, e_o=4.0, e_r=1.0))


def test_alarm_event_fields_are_the_message_definition() -> None:
    fields, constants = definition("AlarmEvent")
    frame_fields, _ = definition("AlarmFrame")
    assert constants == {"STARTED": ALARM_STARTED, "ENDED": ALARM_ENDED} == {"STARTED": 1, "ENDED": 2}
    got = alarm_event_fields(an_alarm(), "camera_optical", "arm-1")
    assert list(got) == list(fields)
    python_type = {"float64": float, "uint8": int, "string": str, "uint64": int, "string[]": list}
    for name, kind in fields.items():
        if kind == "std_msgs/Header":
            assert got[name] == (Stamp(1, 200_000_001), "camera_optical"), "stamped with its start frame"
        elif kind == "AlarmFrame":
            assert list(got[name]) == list(frame_fields), name
            assert type(got[name]["stamp"]) is Stamp
            assert all(type(got[name][k]) is float for k in frame_fields if k != "stamp")
        else:
            assert type(got[name]) is python_type[kind], name
    assert (got["edge"], got["alarm_id"], got["session_id"], got["robot_id"]) == (1, "a7", "arm-1-abc", "arm-1")
    assert (got["detector"], got["detectors"]) == ("flow", ["flow", "scene"])
    assert (got["start_frame"], got["end_frame"], got["frames_flagged"]) == (12, 0, 5)
    assert (got["alarm_threshold"], got["e_o_threshold"], got["e_r_threshold"]) == (1.0, 1.0, 2.5)
    assert math.isnan(got["e_c_threshold"]) and math.isnan(got["e_b_threshold"]) and math.isnan(got["e_k_threshold"])
    assert got["start"]["stamp"] == Stamp(1, 200_000_001) and got["start"]["score"] == 1.5
    assert got["start"]["e_c"] == 0.2 and math.isnan(got["start"]["e_b"])
    assert got["peak"]["stamp"] == Stamp(1, 500_000_000) and got["peak"]["e_r"] == 1.0


def test_an_ended_alarm_is_stamped_at_its_end_and_an_unknown_edge_is_refused() -> None:
    got = alarm_event_fields(an_alarm("ended"), "cam", "arm-1")
    assert (got["edge"], got["end_frame"], got["header"]) == (ALARM_ENDED, 20, (Stamp(3, 7), "cam"))
    with pytest.raises(ValueError, match="neither a start nor an end"):
        alarm_event_fields(an_alarm("unknown"), "cam", "arm-1")


def test_an_anomaly_map_becomes_the_fields_of_a_mono8_image() -> None:
    pixels = bytes([0, 128, 255, 10, 20, 30])
    score = FrameScore(stamp_ns=5_000_000_002, index=0, frame=0, score=0.0, e_c=None, e_b=None, e_o=0.1,
                       anomaly=False, detector=None, warming_up=False, anomaly_map=gray_png(3, 2, pixels))
    got = anomaly_map_fields(score, "camera_optical")
    assert got is not None
    # sensor_msgs/Image's fields, in order.
    assert list(got) == ["header", "height", "width", "encoding", "is_bigendian", "step", "data"]
    assert got["header"] == (Stamp(5, 2), "camera_optical")
    assert (got["height"], got["width"], got["encoding"], got["is_bigendian"], got["step"]) == (2, 3, "mono8", 0, 3)
    assert got["data"] == pixels
    no_map = FrameScore(stamp_ns=1, index=0, frame=0, score=0.0, e_c=None, e_b=None, e_o=None, anomaly=False,
                        detector=None, warming_up=True)
    assert anomaly_map_fields(no_map, "c") is None
    bad = FrameScore(stamp_ns=1, index=0, frame=0, score=0.0, e_c=None, e_b=None, e_o=None, anomaly=False,
                     detector=None, warming_up=True, anomaly_map=b"not a png")
    with pytest.raises(ValueError):
        anomaly_map_fields(bad, "c")
