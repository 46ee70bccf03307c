"""`vamos_msgs` built by colcon, read by a ROS 2 node through its generated types, from
both bridges: `vamos bridge` (Rust, RustDDS) and the `vamos_bridge` node (Python, rclpy).

`clients/ros2/tools/colcon_build.sh` builds `vamos_msgs` and `vamos_bridge` with colcon,
ament_cmake and the rosidl generators of ROS 2 Kilted, all from their wheels on PyPI
(scripts/test.sh does it into `target/ros2_ws` and sources its `install/setup.sh` before
this file runs). A node of rclpy on Fast DDS (`rmw_fastrtps_cpp`) plays a recorded
episode to the bridge under test, run with anomaly maps on against a live `vamos serve`
whose profile flags every frame (`[thresholds] alarm = 0.0`, so an alarm is certain), and
subscribes with the generated `vamos_msgs/msg/FrameScore` and `vamos_msgs/msg/AlarmEvent`
(and `sensor_msgs/Image` for the maps): every field is read through rosidl's C type
support and Fast DDS, from the bytes RustDDS wrote or the node published. The Python
node runs as colcon installed it (`lib/vamos_bridge/bridge`, what `ros2 run` starts),
with the vamos Python client in the same environment.

Without the built packages this file is skipped, unless `REQUIRE_VAMOS_MSGS=1` (as
scripts/test.sh sets) makes that a failure. Needs `VAMOS_BIN`.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT / "clients" / "python" / "tests"))
sys.path.insert(0, str(HERE))

from _ros import EPISODE, read_episode, ros_context, stamp_ns  # noqa: E402
from _server import ROBOT, Server, vamos_bin  # noqa: E402

MODEL = ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos"
MSG_SOURCES = ROOT / "clients" / "ros2" / "vamos_msgs" / "msg"
DETECTORS = {"camera", "body", "flow", "scene", "kinematics"}


BUILD_HINT = ("clients/ros2/tools/colcon_build.sh .venv-ros target/ros2_ws vamos_msgs vamos_bridge, "
              "then . target/ros2_ws/install/setup.sh")


def missing(what: str) -> None:
    """Skips the test, or fails it with REQUIRE_VAMOS_MSGS=1 (scripts/test.sh)."""
    if os.environ.get("REQUIRE_VAMOS_MSGS") == "1":
        raise AssertionError(f"{what} ({BUILD_HINT})")
    pytest.skip(f"{what}: {BUILD_HINT}")


def built_vamos_msgs() -> Any:
    """The `vamos_msgs` package colcon installed; its installed definitions must be this
    checkout's."""
    try:
        import vamos_msgs
        import vamos_msgs.msg  # noqa: F401
    except ImportError as e:
        missing(f"vamos_msgs is not built ({e})")
    # <install>/vamos_msgs/lib/pythonX.Y/site-packages/vamos_msgs/__init__.py
    prefix = Path(vamos_msgs.__file__).resolve().parents[4]
    for name in ("FrameScore.msg", "AlarmEvent.msg", "AlarmFrame.msg"):
        installed = prefix / "share" / "vamos_msgs" / "msg" / name
        assert installed.is_file(), f"{installed}: not a colcon install space"
        assert installed.read_text() == (MSG_SOURCES / name).read_text(), f"{installed} is out of date: build again"
    return vamos_msgs.msg


def python_node_command(ros_args: list[str]) -> list[str]:
    """The `vamos_bridge` node as colcon installed it, with ``ros_args`` after
    ``--ros-args``."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        prefix = Path(get_package_prefix("vamos_bridge"))
    except PackageNotFoundError:
        missing("vamos_bridge is not built")
    script = prefix / "lib" / "vamos_bridge" / "bridge"
    assert script.is_file(), f"{script}: colcon did not install the node's script"
    try:
        import vamos.client  # noqa: F401
    except ImportError as e:
        missing(f"the vamos Python client is not installed here ({e}): pip install ./clients/python")
    return [sys.executable, str(script), "--ros-args", *ros_args]


@pytest.fixture
def ros() -> Iterator[Any]:
    """rclpy on Fast DDS in a domain of its own."""
    with ros_context() as r:
        yield r


@pytest.mark.parametrize("which", ["vamos bridge", "vamos_bridge node"])
def test_generated_vamos_msgs_carry_the_bridges_scores_alarm_and_maps(which: str, ros: Any, tmp_path: Path) -> None:
    rclpy, context, domain = ros
    msgs = built_vamos_msgs()
    FrameScore, AlarmEvent = msgs.FrameScore, msgs.AlarmEvent
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image, JointState

    bin = vamos_bin()
    server = Server(bin, tmp_path / "server", profile_keys=f'model = "{MODEL}"\n',
                    profile_extra="[thresholds]\nalarm = 0.0\n")
    log = tmp_path / "bridge.log"
    bridge = None
    node = rclpy.create_node("robot_player", namespace="robot1", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    frame_scores: list[Any] = []
    alarms: list[Any] = []
    maps: list[Any] = []
    score_sub = node.create_subscription(FrameScore, "vamos/frame_score", frame_scores.append, 100)
    # As a console that wants the alarms it missed would ask: reliable, transient-local.
    alarm_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
    alarm_sub = node.create_subscription(AlarmEvent, "vamos/alarm", alarms.append, alarm_qos)
    map_sub = node.create_subscription(Image, "vamos/anomaly_map", maps.append, 100)
    image_pub = node.create_publisher(Image, "camera/image_raw", 10)
    info_pub = node.create_publisher(CameraInfo, "camera/camera_info", 10)
    joints_pub = node.create_publisher(JointState, "joint_states", 100)

    def wait_for(what: str, done: Callable[[], bool], timeout_s: float = 30) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert bridge is None or bridge.poll() is None, f"the bridge exited:\n{log.read_text()}"
            if time.monotonic() > deadline:
                if bridge is not None:  # its report (what it sent and published) ends the log
                    bridge.send_signal(signal.SIGTERM)
                    bridge.wait(timeout=20)
                raise AssertionError(f"timed out waiting for {what} ({len(frame_scores)} scores, {len(alarms)} "
                                     f"alarm events, {len(maps)} maps received); bridge log:\n{log.read_text()}")
            executor.spin_once(timeout_sec=0.05)

    try:
        reference = sorted(server.offline(EPISODE), key=lambda r: int(r["stamp_ns"]))
        assert len(reference) >= 20
        if which == "vamos bridge":
            command = [str(bin), "bridge", "--server", f"http://{server.grpc}", "--profile", "sim-arm",
                       "--namespace", "robot1", "--domain-id", str(domain), "--anomaly-maps"]
            env = dict(server.env, VAMOS_ROBOT_TOKEN=ROBOT, VAMOS_LOG__LEVEL="info")
        else:
            command = python_node_command(["-r", "__ns:=/robot1", "-p", "profile:=sim-arm",
                                           "-p", f"server:={server.grpc}", "-p", "anomaly_maps:=true"])
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain), VAMOS_TOKEN=ROBOT)
        with log.open("wb") as err:
            bridge = subprocess.Popen(command, stdout=err, stderr=subprocess.STDOUT, env=env)
        outputs = ("/robot1/vamos/frame_score", "/robot1/vamos/alarm", "/robot1/vamos/anomaly_map")
        wait_for("the bridge's subscriptions", lambda: all(
            p.get_subscription_count() > 0 for p in (image_pub, info_pub, joints_pub)))
        wait_for("the bridge's publishers", lambda: all(node.count_publishers(t) > 0 for t in outputs)
                 and all(sub.get_publisher_count() > 0 for sub in (score_sub, alarm_sub, map_sub)))
        topics = dict(node.get_topic_names_and_types())
        assert topics["/robot1/vamos/frame_score"] == ["vamos_msgs/msg/FrameScore"], topics
        assert topics["/robot1/vamos/alarm"] == ["vamos_msgs/msg/AlarmEvent"], topics
        assert topics["/robot1/vamos/anomaly_map"] == ["sensor_msgs/msg/Image"], topics

        # Our writers have matched the bridge's readers, and our readers its writers; that
        # the bridge's readers know our writers (RustDDS drops samples of writers it has not
        # discovered yet) cannot be seen from here: a second for its discovery to finish.
        settle = time.monotonic() + 1.0
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)
        messages = read_episode(EPISODE)
        images = [m for kind, m in messages if kind == "image"]
        sent = 0
        for kind, m in messages:
            if kind == "image":
                # A robot within the server's queue: at most three images ahead of the scores.
                wait_for("scores", lambda n=sent: len(frame_scores) >= n - 3)
                image_pub.publish(m)
                sent += 1
            elif kind == "camera_info":
                info_pub.publish(m)
            else:
                joints_pub.publish(m)
        # The last images are scored once the session ends: SIGTERM (the node: SIGINT, as
        # Ctrl-C), then read until it exits.
        time.sleep(0.5)
        bridge.send_signal(signal.SIGTERM if which == "vamos bridge" else signal.SIGINT)
        wait_for("the bridge to finish", lambda: bridge.poll() is not None, 30)
        assert bridge.returncode == 0, log.read_text()
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        if bridge is not None and bridge.poll() is None:
            bridge.kill()
            bridge.wait()
        executor.shutdown()
        node.destroy_node()
        server.stop()

    # FrameScore: one per image, in order, with its image's header and the offline
    # scores. The flow predictor samples its futures with a seed of the session (a live
    # session's differs from `vamos score`'s), so e_o is compared by presence only, and
    # the fused score wherever neither run's score came from e_o.
    assert len(frame_scores) == len(images) == len(reference), (len(frame_scores), len(images), len(reference))
    session_id = frame_scores[0].session_id
    assert session_id.startswith("robot1-"), session_id
    for fs, image, want in zip(frame_scores, images, reference, strict=True):
        assert isinstance(fs, FrameScore)
        assert stamp_ns(fs.header.stamp) == stamp_ns(image.header.stamp) == int(want["stamp_ns"])
        assert fs.header.frame_id == image.header.frame_id
        assert fs.frame == int(want["frame"]) and fs.session_id == session_id
        for e in ("e_c", "e_b", "e_r", "e_k"):
            if want[e] is None:
                assert math.isnan(getattr(fs, e)), (e, fs)
            else:
                assert math.isclose(getattr(fs, e), want[e], rel_tol=1e-9, abs_tol=1e-12), (e, fs, want)
        assert math.isnan(fs.e_o) == (want["e_o"] is None), (fs, want)
        # The detector that set the score (`vamos score` calls it `triggered`).
        assert fs.detector in DETECTORS | {""}, fs
        if "flow" not in (fs.detector, want["triggered"]):
            assert math.isclose(fs.score, want["score"], rel_tol=1e-9, abs_tol=1e-12), (fs, want)
            assert fs.detector == (want["triggered"] or "") and fs.anomaly == bool(want["anomaly"])
        assert fs.warming_up == bool(want["warming_up"]) and fs.latency_s >= 0
    # With alarm threshold 0 every frame after the first is flagged.
    flags = [fs.anomaly for fs in frame_scores]
    assert sum(flags) >= len(flags) - 1, flags

    # AlarmEvent: the alarm started where 3 of the last 5 frames were flagged, stamped
    # with that frame's image, carrying the thresholds and that frame's components.
    assert alarms, f"no alarm event; bridge log:\n{log.read_text()}"
    started = alarms[0]
    assert isinstance(started, AlarmEvent)
    assert started.edge == AlarmEvent.STARTED == 1 and AlarmEvent.ENDED == 2
    first = next(i for i in range(len(flags)) if sum(flags[max(0, i - 4):i + 1]) >= 3)
    at = frame_scores[first]
    assert started.start_frame == at.frame and started.end_frame == 0
    assert stamp_ns(started.header.stamp) == stamp_ns(at.header.stamp) == stamp_ns(started.start.stamp)
    assert started.header.frame_id == at.header.frame_id != ""
    assert (started.robot_id, started.session_id) == ("robot1", session_id)
    assert started.alarm_id and started.frames_flagged >= 1
    assert started.detector in DETECTORS and started.detector in list(started.detectors), started
    assert started.alarm_threshold == 0.0
    assert started.start.score == at.score and started.peak.score == at.score
    for e in ("e_c", "e_b", "e_o", "e_r", "e_k"):
        have, want = getattr(started.start, e), getattr(at, e)
        assert (math.isnan(have) and math.isnan(want)) or have == want, (e, have, want)
    # Every frame stays flagged: the alarm never ends while the episode lasts.
    assert [a.edge for a in alarms] == [AlarmEvent.STARTED], [(a.edge, a.alarm_id) for a in alarms]

    # Anomaly maps: mono8 images stamped like their frames, one for each frame with e_o.
    with_map = [fs for fs, want in zip(frame_scores, reference, strict=True) if want.get("e_o") is not None]
    assert with_map and len(maps) == len(with_map), (len(maps), len(with_map))
    for m, fs in zip(maps, with_map, strict=True):
        assert (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id) == \
            (fs.header.stamp.sec, fs.header.stamp.nanosec, fs.header.frame_id)
        assert m.encoding == "mono8" and m.step == m.width > 0 and m.height > 0
        assert len(m.data) == m.width * m.height
    assert any(any(m.data) for m in maps), "every map is blank"
