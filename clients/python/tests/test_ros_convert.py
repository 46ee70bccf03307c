"""The ROS 2 bridge's conversions and bookkeeping, without ROS (messages are stand-ins
with the fields of sensor_msgs)."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace as NS

import pytest

pytest.importorskip("grpc")

from vamos.client import FrameScore, SessionEvent  # noqa: E402
from vamos.ros.convert import ERROR, OK, STALE, WARN, BridgeState, camera_info, image_request, joints_request  # noqa: E402


def header(sec: int, nanosec: int) -> NS:
    return NS(stamp=NS(sec=sec, nanosec=nanosec), frame_id="camera")


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
    with pytest.raises(ValueError):
        image_request(NS(header=header(1, 0), format="theora", data=b"x"))
    j = joints_request(NS(header=header(2, 7), name=["a", "b"], position=[0.1, 0.2], velocity=[],
                          effort=[1.0, 2.0]))
    assert (j.joints.stamp_ns, list(j.joints.names), list(j.joints.efforts)) == (2_000_000_007, ["a", "b"], [1.0, 2.0])
    c = camera_info(NS(width=640, height=480, k=[500.0, 0, 320, 0, 505, 240, 0, 0, 1]))
    assert (c.fx, c.fy, c.cx, c.cy, c.width) == (500.0, 505.0, 320.0, 240.0, 640)


def score(anomaly: bool, warming: bool = False) -> FrameScore:
    return FrameScore(stamp_ns=1, index=0, frame=0, score=2.5 if anomaly else 0.1, e_c=None, e_b=None,
                      e_o=None, anomaly=anomaly, detector="flow" if anomaly else None,
                      warming_up=warming, latency_s=0.02)


def test_the_bridge_state_drives_its_outputs_and_diagnostics() -> None:
    st = BridgeState()
    level, message, _ = st.diagnostic(now=0.0)
    assert level == ERROR and "not connected" in message
    st.on_update(SessionEvent("opened", "robot-1", "session robot-1 profile p model m"))
    assert st.connected and st.session_id == "robot-1"
    assert st.diagnostic(now=100.0)[0] == STALE
    st.on_sent_image(now=100.0)
    assert st.diagnostic(now=100.5)[:2] == (WARN, "images sent but no scores back")
    assert st.on_update(score(False, warming=True), now=100.6) == (0.1, False)
    assert st.diagnostic(now=100.7)[:2] == (OK, "scoring (flow predictor warming up)")
    assert st.on_update(score(True), now=100.8) == (2.5, True)
    level, message, values = st.diagnostic(now=100.9)
    assert (level, message) == (OK, "scoring")
    assert dict(values)["anomaly"] == "True" and dict(values)["frames_scored"] == "2"
    st.on_update(SessionEvent("frames_dropped", "robot-1", "queue full", count=3))
    st.on_update(SessionEvent("message_error", "robot-1", "image refused: bad size"))
    level, message, _ = st.diagnostic(now=101.0)
    assert level == WARN and "3 image(s) dropped, 1 message(s) refused" == message
    # No images for a while: stale.
    assert st.diagnostic(now=200.0)[0] == STALE


def test_the_node_says_what_it_needs_without_ros() -> None:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        pass
    else:  # pragma: no cover - only where ROS 2 is sourced
        pytest.skip("ROS 2 is installed here; the node runs for real")
    run = subprocess.run([sys.executable, "-m", "vamos.ros.node"], capture_output=True, text=True,
                         env={"PYTHONPATH": str(__import__("pathlib").Path(__file__).resolve().parents[1] / "src")})
    assert run.returncode == 2
    assert "sourced ROS 2" in run.stdout
