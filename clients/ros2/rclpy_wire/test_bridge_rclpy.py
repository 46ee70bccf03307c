"""`vamos bridge` against a real ROS 2 node: rclpy on eProsima Fast DDS.

The bridge is written on RustDDS (ros2-client). Here the other side is ROS 2 itself: rclpy
from the ROS 2 wheels on PyPI (`ros-rclpy` and its `ros-*` dependencies, ROS 2 Kilted), with
`rmw_fastrtps_cpp`, the default middleware of ROS 2 (Fast DDS). A node plays a recorded
episode as `sensor_msgs/Image`, `CameraInfo` and `JointState` under a namespace (and
another robot's camera beside it), subscribes to the bridge's `std_msgs` scores and
`diagnostic_msgs` status through rclpy's own type support, and lists the bridge in the
ROS graph. The scores must be those `vamos score` gives the same bag with the same profile.

These wheels are kept out of the main environment: scripts/test.sh runs this file from its
own virtual environment (`.venv-ros`, clients/ros2/rclpy_wire/requirements.txt). Needs
`VAMOS_BIN`; skipped without it or without rclpy.
"""

from __future__ import annotations

import math
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

from _ros import EPISODE, read_episode, ros_context  # noqa: E402
from _server import ROBOT, Server, vamos_bin  # noqa: E402


@pytest.fixture
def ros() -> Iterator[Any]:
    """rclpy on Fast DDS in a domain of its own."""
    with ros_context() as r:
        yield r


def test_a_ros2_node_on_fast_dds_gets_the_scores_vamos_score_gives(ros: Any, tmp_path: Path) -> None:
    rclpy, context, domain = ros
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import CameraInfo, Image, JointState
    from std_msgs.msg import Bool, Float64

    bin = vamos_bin()
    server = Server(bin, tmp_path / "server")
    log = tmp_path / "bridge.log"
    bridge = None
    node = rclpy.create_node("robot_player", namespace="robot1", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    scores: list[float] = []
    anomalies: list[bool] = []
    statuses: list[Any] = []
    node.create_subscription(Float64, "vamos/score", lambda m: scores.append(m.data), 100)
    node.create_subscription(Bool, "vamos/anomaly", lambda m: anomalies.append(m.data), 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: statuses.extend(m.status), 100)
    image_pub = node.create_publisher(Image, "camera/image_raw", 10)
    info_pub = node.create_publisher(CameraInfo, "camera/camera_info", 10)
    joints_pub = node.create_publisher(JointState, "joint_states", 100)
    other_pub = node.create_publisher(Image, "/robot2/camera/image_raw", 10)

    def wait_for(what: str, done: Callable[[], bool], timeout_s: float = 30) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert bridge is None or bridge.poll() is None, f"the bridge exited:\n{log.read_text()}"
            assert time.monotonic() < deadline, f"timed out waiting for {what}; bridge log:\n{log.read_text()}"
            executor.spin_once(timeout_sec=0.05)

    try:
        reference = sorted(server.offline(EPISODE), key=lambda r: int(r["stamp_ns"]))
        assert len(reference) >= 20
        with log.open("wb") as err:
            bridge = subprocess.Popen(
                [str(bin), "bridge", "--server", f"http://{server.grpc}", "--profile", "sim-arm",
                 "--namespace", "robot1", "--domain-id", str(domain), "--diagnostics-period", "0.2"],
                stdout=subprocess.DEVNULL, stderr=err,
                env=dict(server.env, VAMOS_ROBOT_TOKEN=ROBOT, VAMOS_LOG__LEVEL="info"))
        # The bridge is in the ROS graph: its node, and both ends of every topic matched.
        wait_for("the bridge's node in the graph",
                 lambda: ("vamos_bridge", "/robot1") in node.get_node_names_and_namespaces())
        wait_for("the bridge's subscriptions", lambda: all(
            p.get_subscription_count() > 0 for p in (image_pub, info_pub, joints_pub)))
        wait_for("the bridge's publishers", lambda: node.count_publishers("/robot1/vamos/score") > 0
                 and node.count_publishers("/diagnostics") > 0)
        topics = dict(node.get_topic_names_and_types())
        assert topics["/robot1/vamos/score"] == ["std_msgs/msg/Float64"], topics
        assert topics["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"], topics
        # Anomaly maps are off unless asked for: no map topic.
        assert "/robot1/vamos/anomaly_map" not in topics, topics

        messages = read_episode(EPISODE)
        images = [m for kind, m in messages if kind == "image"]
        sent = 0
        for kind, m in messages:
            if kind == "image":
                # A robot within the server's queue: at most three images ahead of the scores.
                wait_for("scores", lambda n=sent: len(scores) >= n - 3)
                image_pub.publish(m)
                other_pub.publish(m)
                sent += 1
            elif kind == "camera_info":
                info_pub.publish(m)
            else:
                joints_pub.publish(m)
        # The last images are scored once the session ends: SIGTERM, then read until it exits.
        time.sleep(0.5)
        bridge.send_signal(signal.SIGTERM)
        wait_for("the bridge to finish", lambda: bridge.poll() is not None, 20)
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

    # One score per image of robot1 (robot2's never entered the session), in image order,
    # equal to the offline scores.
    assert len(scores) == len(reference) == len(images), (len(scores), len(reference), len(images))
    for have, want in zip(scores, reference, strict=True):
        assert math.isclose(have, want["score"], rel_tol=1e-9, abs_tol=1e-12), (have, want)
    assert anomalies == [bool(r["anomaly"]) for r in reference]
    mine = [st for st in statuses if st.hardware_id == "robot1"]
    assert mine and all(st.name == "vamos: /robot1/vamos_bridge" for st in mine)
    assert any(st.level == b"\x00" or st.level == 0 for st in mine if st.message.startswith("scoring")), \
        [(st.level, st.message) for st in mine]
    values = {kv.key: kv.value for kv in mine[-1].values}
    assert int(values["images_sent"]) == len(images), values
    assert values["image_topic"] == "/robot1/camera/image_raw"
