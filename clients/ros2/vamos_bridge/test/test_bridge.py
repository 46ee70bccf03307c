"""The bridge without ROS: its state and diagnostics, the session's life (opening at
the first image, early joint states, reconnects), and a recorded robot fed through it
to the real ``vamos serve`` (``VAMOS_BIN``): the decoded ROS 2 messages of a bag stand in
for the subscriptions' messages, and every published FrameScore must carry its image's
stamp and frame_id and the score ``vamos score`` gives offline."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

from vamos.client import FrameScore, SessionError, SessionEvent
from vamos_bridge.bridge import ERROR, OK, STALE, WARN, Bridge, BridgeState, CallbackOutputs
from vamos_bridge.convert import Stamp
from vamos_bridge.params import Params

ROOT = Path(__file__).resolve().parents[4]


def score(anomaly: bool, warming: bool = False, stamp_ns: int = 1) -> FrameScore:
    return FrameScore(stamp_ns=stamp_ns, index=0, frame=0, score=2.5 if anomaly else 0.1, e_c=None, e_b=None,
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
    assert st.diagnostic(now=200.0)[0] == STALE


class Recorder:
    """The node's side: what the bridge published and logged."""

    def __init__(self) -> None:
        self.scores: list[dict[str, Any]] = []
        self.alarms: list[dict[str, Any]] = []
        self.maps: list[dict[str, Any]] = []
        self.logs: list[tuple[str, str]] = []
        self.done = threading.Event()

    def score(self, fields: dict[str, Any]) -> None:
        self.scores.append(fields)

    def alarm(self, fields: dict[str, Any]) -> None:
        self.alarms.append(fields)

    def anomaly_map(self, fields: dict[str, Any]) -> None:
        self.maps.append(fields)

    def log(self, level: str, text: str) -> None:
        self.logs.append((level, text))


class FakeSession:
    """A session that answers each image with a score of its stamp, until ``broken``."""

    def __init__(self, session_id: str) -> None:
        self.sent: list[Any] = []
        self.opened = SessionEvent("opened", session_id, "")
        self.answers: "list[Any]" = []
        self.cond = threading.Condition()
        self.finished = self.broken = False

    def send(self, request: Any) -> None:
        with self.cond:
            self.sent.append(request)
            if request.WhichOneof("message") == "image":
                self.answers.append(score(False, stamp_ns=request.image.stamp_ns))
            self.cond.notify_all()

    def finish(self) -> None:
        with self.cond:
            self.finished = True
            self.cond.notify_all()

    def __iter__(self) -> Iterator[Any]:
        while True:
            with self.cond:
                self.cond.wait_for(lambda: self.answers or self.finished or self.broken)
                if self.broken:
                    raise SessionError("UNAVAILABLE", "connection reset")
                if not self.answers:
                    return
                item = self.answers.pop(0)
            yield item


class FakeClient:
    def __init__(self, refuse_first: bool = False) -> None:
        self.sessions: list[FakeSession] = []
        self.opens: list[dict[str, Any]] = []
        self.refuse = refuse_first

    def open_session(self, profile: str, **kw: Any) -> FakeSession:
        self.opens.append({"profile": profile, **kw})
        if self.refuse:
            self.refuse = False
            raise SessionError("UNAVAILABLE", "server down")
        s = FakeSession(kw["session_id"])
        self.sessions.append(s)
        return s


def header(ns: int, frame_id: str) -> Any:
    from types import SimpleNamespace as NS

    return NS(stamp=NS(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame_id)


def image(ns: int, frame_id: str = "cam") -> Any:
    from types import SimpleNamespace as NS

    return NS(header=header(ns, frame_id), height=1, width=1, encoding="mono8", is_bigendian=0, step=1,
              data=b"\x00")


def joints(ns: int) -> Any:
    from types import SimpleNamespace as NS

    return NS(header=header(ns, ""), name=["j1"], position=[0.5], velocity=[], effort=[])


def wait_for(cond: Any, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_the_session_opens_at_the_first_image_and_reconnects_under_its_id() -> None:
    from types import SimpleNamespace as NS

    params = Params.from_values({"profile": "p", "task": "shelf"}, "/robot1", "vamos_bridge", suffix="abc")
    client, out = FakeClient(refuse_first=True), Recorder()
    bridge = Bridge(params, client, CallbackOutputs(out.score, out.log, out.alarm, out.anomaly_map), reopen_after_s=0.2)
    bridge.on_camera_info(NS(width=0, height=0, k=[0.0] * 9))  # uncalibrated: ignored, logged
    bridge.on_camera_info(NS(width=160, height=120, k=[100.0, 0, 80, 0, 100, 60, 0, 0, 1]))
    bridge.on_joint_state(joints(1))
    bridge.on_joint_state(joints(2))
    bridge.on_image(image(3))  # the server refuses the first open: nothing sent, ERROR
    assert bridge.diagnostic(now=0.0)[0] == ERROR and client.sessions == []
    bridge.on_image(image(4))  # within reopen_after_s of the refusal: dropped, no new try
    assert len(client.opens) == 1 and bridge.state.images_sent == 0
    time.sleep(0.25)
    bridge.on_image(image(10**9 + 5, "cam_left"))
    (s,) = client.sessions
    assert client.opens[-1] == {"profile": "p", "robot_id": "robot1", "session_id": "robot1-abc", "task": "shelf",
                                "camera_info": bridge.camera, "anomaly_maps": False}
    # The early joint states first, then the image.
    assert [m.WhichOneof("message") for m in s.sent] == ["joints", "joints", "image"]
    wait_for(lambda: len(out.scores) == 1)
    assert out.scores[0]["header"] == (Stamp(1, 5), "cam_left")
    assert out.scores[0]["session_id"] == "robot1-abc"
    # The stream breaks: the next image reopens the same session id.
    with s.cond:
        s.broken = True
        s.cond.notify_all()
    wait_for(lambda: bridge.state.reconnects == 1)
    bridge.on_image(image(2 * 10**9, "cam_left"))
    assert len(client.sessions) == 2 and client.opens[-1]["session_id"] == "robot1-abc"
    wait_for(lambda: len(out.scores) == 2)
    assert out.scores[1]["header"] == (Stamp(2, 0), "cam_left")
    # A compressed image vamos cannot decode is refused here, not sent.
    bridge.on_image(NS(header=header(3, "c"), format="theora", data=b"x"))
    assert bridge.state.refused == 1
    bridge.close()
    assert client.sessions[1].finished
    warnings = [text for level, text in out.logs if level == "warning"]
    assert any("camera info ignored" in w for w in warnings) and any("cannot open" in w for w in warnings)
    assert any("stream ended" in w for w in warnings) and any("image ignored" in w for w in warnings)
    values = dict(bridge.diagnostic()[2])
    assert values["image_topic"] == "/robot1/camera/image_raw" and values["robot_id"] == "robot1"


def test_alarm_events_and_anomaly_maps_go_out_stamped_like_their_frames() -> None:
    from test_convert import an_alarm, gray_png

    params = Params.from_values({"profile": "p", "anomaly_maps": True}, "/robot1", "vamos_bridge", suffix="m")
    assert params.resolved["alarm_topic"] == "/robot1/vamos/alarm"
    assert params.resolved["anomaly_map_topic"] == "/robot1/vamos/anomaly_map"
    client, out = FakeClient(), Recorder()
    bridge = Bridge(params, client, CallbackOutputs(out.score, out.log, out.alarm, out.anomaly_map))
    bridge.on_image(image(1_200_000_001, "cam_left"))
    (s,) = client.sessions
    assert client.opens[-1]["anomaly_maps"] is True, "maps are asked for"
    wait_for(lambda: len(out.scores) == 1)
    assert out.maps == [], "a score without a map publishes none"
    # The server's answers to the next image: its score with a map, then an alarm that
    # started at it, an alarm event of an unknown edge, and a map that is not a PNG.
    bridge.on_image(image(1_300_000_000, "cam_right"))
    wait_for(lambda: len(out.scores) == 2)
    stamp = 1_400_000_000
    bridge.frame_ids.remember(stamp, "cam_right")
    with s.cond:
        s.answers += [FrameScore(stamp_ns=stamp, index=2, frame=2, score=3.0, e_c=None, e_b=None, e_o=3.0,
                                 anomaly=True, detector="flow", warming_up=False,
                                 anomaly_map=gray_png(2, 1, b"\x00\xff")),
                      an_alarm(), an_alarm("unknown"),
                      FrameScore(stamp_ns=stamp + 1, index=3, frame=3, score=3.0, e_c=None, e_b=None, e_o=3.0,
                                 anomaly=True, detector="flow", warming_up=False, anomaly_map=b"garbage")]
        s.cond.notify_all()
    wait_for(lambda: len(out.scores) == 4)
    (m,) = out.maps
    assert (m["header"], m["width"], m["height"], m["encoding"], m["data"]) == (
        (Stamp(1, 400_000_000), "cam_right"), 2, 1, "mono8", b"\x00\xff")
    (a,) = out.alarms
    # The alarm's own stamp (its start frame's), the frame id of the score before it.
    assert a["header"] == (Stamp(1, 200_000_001), "cam_right")
    assert (a["edge"], a["alarm_id"], a["robot_id"], a["detector"]) == (1, "a7", "robot1", "flow")
    warnings = [text for level, text in out.logs if level == "warning"]
    assert any("alarm event not published" in w for w in warnings), warnings
    assert any("anomaly map of frame 3 not published" in w for w in warnings), warnings
    assert any("alarm a7 started" in text for level, text in out.logs if level == "info"), out.logs
    bridge.close()
    # Without anomaly_maps none are asked for, and none published.
    params = Params.from_values({"profile": "p"}, "/robot1", "vamos_bridge", suffix="n")
    assert "anomaly_map_topic" not in params.resolved
    client, out = FakeClient(), Recorder()
    bridge = Bridge(params, client, CallbackOutputs(out.score, out.log, out.alarm, out.anomaly_map))
    bridge.on_image(image(1))
    assert client.opens[-1]["anomaly_maps"] is False
    with client.sessions[0].cond:
        client.sessions[0].answers.append(FrameScore(
            stamp_ns=2, index=1, frame=1, score=0.0, e_c=None, e_b=None, e_o=0.0, anomaly=False, detector=None,
            warming_up=False, anomaly_map=gray_png(1, 1, b"\x01")))
        client.sessions[0].cond.notify_all()
    wait_for(lambda: len(out.scores) == 2)
    bridge.close()
    assert out.maps == []


def real_server() -> Any:
    """What a test against the real server needs: the Python tests' server harness, the
    MCAP reader and the client (skipped without the MCAP decoder)."""
    from types import SimpleNamespace as NS

    sys.path.insert(0, str(ROOT / "clients" / "python" / "tests"))
    try:
        from _server import ROBOT, SIM, Server, vamos_bin
    finally:
        sys.path.pop(0)
    pytest.importorskip("mcap_ros2.decoder")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from vamos.client import MonitorClient
    return NS(ROBOT=ROBOT, SIM=SIM, Server=Server, vamos_bin=vamos_bin, make_reader=make_reader,
              DecoderFactory=DecoderFactory, MonitorClient=MonitorClient)


def test_a_recorded_robot_through_the_bridge_to_the_real_server(tmp_path: Path) -> None:
    r = real_server()
    ROBOT, SIM, Server, vamos_bin = r.ROBOT, r.SIM, r.Server, r.vamos_bin
    make_reader, DecoderFactory, MonitorClient = r.make_reader, r.DecoderFactory, r.MonitorClient

    episode = SIM / "test" / "test_0001_external_push.mcap"
    server = Server(vamos_bin(), tmp_path / "server")
    try:
        offline = server.offline(episode)
        params = Params.from_values({"profile": "sim-arm"}, "/arm_1", "vamos_bridge", suffix="e2e")
        out = Recorder()
        with MonitorClient(server.grpc, token=ROBOT) as client, open(episode, "rb") as fh:
            bridge = Bridge(params, client, out)
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            frame_ids = {}
            for schema, _channel, _message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
                if schema.name == "sensor_msgs/msg/Image":
                    # A live camera does not wait; here the bag would outrun the server's
                    # queue, so keep at most 4 images unanswered.
                    wait_for(lambda: bridge.state.images_sent - len(out.scores) < 4, timeout=120)
                    frame_ids[ros_msg.header.stamp.sec * 10**9 + ros_msg.header.stamp.nanosec] = \
                        ros_msg.header.frame_id
                    bridge.on_image(ros_msg)
                elif schema.name == "sensor_msgs/msg/JointState":
                    bridge.on_joint_state(ros_msg)
                elif schema.name == "sensor_msgs/msg/CameraInfo":
                    bridge.on_camera_info(ros_msg)
            bridge.close(timeout_s=120)
        assert bridge.state.dropped == 0 and bridge.state.refused == 0, out.logs
        assert len(out.scores) == len(offline) > 10, (len(out.scores), len(offline))
        for fields, o in zip(out.scores, offline, strict=True):
            stamp, frame_id = fields["header"]
            ns = stamp.sec * 10**9 + stamp.nanosec
            assert ns == o["stamp_ns"] and frame_id == frame_ids[ns] and frame_id
            assert (fields["score"], fields["anomaly"]) == (o["score"], o["anomaly"])
            assert fields["session_id"] == "arm_1-e2e"
    finally:
        stderr = server.stop()
    assert server.proc.returncode == 0, stderr


def depth(ns: int, width: int = 2, height: int = 1) -> Any:
    """A 16UC1 depth image (1.5 m everywhere) whose width says which it is."""
    from types import SimpleNamespace as NS

    return NS(header=header(ns, "depth"), height=height, width=width, encoding="16UC1", is_bigendian=0,
              step=2 * width, data=(1500).to_bytes(2, "little") * (width * height))


def test_images_go_with_the_depth_image_nearest_their_stamp() -> None:
    ms = 1_000_000
    params = Params.from_values({"profile": "p", "depth_topic": "camera/depth/image_raw"}, "/robot1", "vamos_bridge",
                                suffix="d")
    assert params.resolved["depth_topic"] == "/robot1/camera/depth/image_raw"
    client, out = FakeClient(), Recorder()
    bridge = Bridge(params, client, CallbackOutputs(out.score, out.log, out.alarm, out.anomaly_map))
    bridge.WITHOUT_DEPTH_WARNING = 3
    # A depth image at or after the image's stamp first, then the image: out at once,
    # with it.
    bridge.on_depth(depth(1006 * ms, width=4))
    bridge.on_image(image(1000 * ms + 4 * ms, "cam"))
    (s,) = client.sessions

    def sent() -> list[tuple[int, int]]:
        """(stamp, depth width or 0) of the images the session got."""
        return [(m.image.stamp_ns, m.image.depth.width if m.image.HasField("depth") else 0)
                for m in s.sent if m.WhichOneof("message") == "image"]

    assert sent() == [(1004 * ms, 4)]
    # The image first: it waits for a depth image at or after its stamp, and takes the
    # nearest within 20 ms.
    bridge.on_image(image(1100 * ms))
    assert sent() == [(1004 * ms, 4)] and bridge._pairer is not None and bridge._pairer.held()[0] == 1
    bridge.on_depth(depth(1090 * ms, width=6))
    bridge.on_depth(depth(1115 * ms, width=8))
    assert sent()[1:] == [(1100 * ms, 6)]
    # No depth image near: the image waits for its hold (40 ms), then goes without one.
    bridge.on_image(image(1300 * ms))
    bridge.release_due(now=time.monotonic() + 0.041)
    assert sent()[2:] == [(1300 * ms, 0)]
    bridge.on_image(image(1400 * ms))
    bridge.on_image(image(1500 * ms))
    bridge.release_due(now=time.monotonic() + 0.041)
    assert sent()[3:] == [(1400 * ms, 0), (1500 * ms, 0)]
    assert [t for level, t in out.logs if "in a row sent without a depth image" in t] == [
        "3 images in a row sent without a depth image: none on /robot1/camera/depth/image_raw within 20 ms of "
        "their stamps; the server uses the profile's assumed depth"]
    # Still waiting when the bridge closes: sent before the session finishes.
    bridge.on_depth(depth(1595 * ms, width=10))
    bridge.on_image(image(1600 * ms))
    bridge.close()
    assert sent()[5:] == [(1600 * ms, 10)] and s.finished
    assert (bridge.state.images_sent, bridge.state.images_with_depth) == (6, 3)
    assert dict(bridge.diagnostic()[2])["images_with_depth"] == "3"
    wait_for(lambda: len(out.scores) == 6)
    assert [f["header"][0] for f in out.scores][:2] == [Stamp(1, 4 * ms), Stamp(1, 100 * ms)]


def test_without_a_depth_topic_images_go_at_once_and_depth_images_are_ignored() -> None:
    params = Params.from_values({"profile": "p"}, "/robot1", "vamos_bridge", suffix="n")
    client, out = FakeClient(), Recorder()
    bridge = Bridge(params, client, CallbackOutputs(out.score, out.log, out.alarm, out.anomaly_map))
    bridge.on_depth(depth(1))
    bridge.on_image(image(1))
    bridge.release_due()
    (s,) = client.sessions
    assert [m.image.HasField("depth") for m in s.sent] == [False]
    bridge.close()
    assert bridge.state.images_with_depth == 0 and "depth_topic" not in dict(bridge.diagnostic()[2])


def test_a_recorded_robot_with_depth_images_through_the_bridge_to_the_real_server(tmp_path: Path) -> None:
    """Each depth image reaches the server with its image: a depth image of another aspect
    ratio paired with an image is refused by the server (one message each), one too far
    from every image is never sent, and every image is scored."""
    r = real_server()
    ROBOT, SIM, Server, vamos_bin = r.ROBOT, r.SIM, r.Server, r.vamos_bin
    make_reader, DecoderFactory, MonitorClient = r.make_reader, r.DecoderFactory, r.MonitorClient

    episode = SIM / "test" / "test_0000.mcap"
    ms = 1_000_000
    server = Server(vamos_bin(), tmp_path / "server")
    try:
        offline = server.offline(episode)
        params = Params.from_values({"profile": "sim-arm", "depth_topic": "camera/depth/image_raw"}, "/arm_1",
                                    "vamos_bridge", suffix="depth")
        out = Recorder()
        paired = refused = 0
        with MonitorClient(server.grpc, token=ROBOT) as client, open(episode, "rb") as fh:
            bridge = Bridge(params, client, out)
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            images = 0
            for schema, _channel, _message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
                if schema.name == "sensor_msgs/msg/Image":
                    wait_for(lambda: bridge.state.images_sent - len(out.scores) < 4, timeout=120)
                    ns = ros_msg.header.stamp.sec * 10**9 + ros_msg.header.stamp.nanosec
                    # The depth camera's image comes first; by turns: a good one 4 ms after
                    # (80x60, the camera's 4:3), one of another aspect ratio 3 ms before,
                    # and one 45 ms after (images are 100 ms apart: within 20 ms of none).
                    kind = images % 3
                    if kind == 0:
                        bridge.on_depth(depth(ns + 4 * ms, width=80, height=60))
                        paired += 1
                    elif kind == 1:
                        bridge.on_depth(depth(ns - 3 * ms, width=50, height=50))
                        paired += 1
                        refused += 1
                    else:
                        bridge.on_depth(depth(ns + 45 * ms, width=50, height=50))
                    images += 1
                    bridge.on_image(ros_msg)
                elif schema.name == "sensor_msgs/msg/JointState":
                    bridge.on_joint_state(ros_msg)
                elif schema.name == "sensor_msgs/msg/CameraInfo":
                    bridge.on_camera_info(ros_msg)
            bridge.close(timeout_s=120)
        assert bridge.state.dropped == 0, out.logs
        assert (bridge.state.images_sent, bridge.state.images_with_depth) == (images, paired)
        # One refusal per paired depth image of another aspect ratio, naming why; no other.
        assert bridge.state.refused == refused > 5, bridge.state
        assert "depth image refused" in bridge.state.last_error and "aspect ratio" in bridge.state.last_error
        # Every image scored, in order.
        assert [f["header"][0] for f in out.scores] == [Stamp(*divmod(o["stamp_ns"], 10**9)) for o in offline]
    finally:
        stderr = server.stop()
    assert server.proc.returncode == 0, stderr
