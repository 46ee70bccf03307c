"""``vamos-ros-bridge``: an rclpy node streaming a robot's topics to ``vamos serve``.

Parameters (``--ros-args -p name:=value``):

- ``server`` (``127.0.0.1:8081``), ``token`` (default ``$VAMOS_TOKEN``), ``ca_file``;
- ``profile`` (required), ``robot_id`` (the node's namespace and name), ``session_id``
  (default: a new id per start; set one to resume after a reconnect), ``task``;
- ``image_topic`` (``/camera/image_raw``), ``compressed`` (false: ``sensor_msgs/Image``,
  true: ``sensor_msgs/CompressedImage``), ``camera_info_topic``
  (``/camera/camera_info``), ``joint_states_topics`` (``["/joint_states"]``);
- outputs: ``score_topic`` (``/vamos/score``, std_msgs/Float64), ``anomaly_topic``
  (``/vamos/anomaly``, std_msgs/Bool), ``diagnostics`` on ``/diagnostics`` at 1 Hz.

The session opens at the first image (so the camera info, if any, has arrived); when the
stream breaks it is resumed (client-chosen ``session_id``) or a new one is opened.
"""

from __future__ import annotations

import collections
import os
import threading
import time
import uuid
from typing import Any, Optional


def main(argv: Optional[list[str]] = None) -> int:
    try:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo as RosCameraInfo
        from sensor_msgs.msg import CompressedImage, Image, JointState
        from std_msgs.msg import Bool, Float64
    except ImportError as e:
        print(f"vamos-ros-bridge needs a sourced ROS 2 installation (rclpy, sensor_msgs, std_msgs, "
              f"diagnostic_msgs): {e}")
        return 2

    from vamos.client import MonitorClient, SessionError

    from .convert import BridgeState, camera_info, image_request, joints_request

    class VamosBridge(Node):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__("vamos_bridge")
            p = self.declare_parameter
            self.server = p("server", "127.0.0.1:8081").value
            self.token = p("token", os.environ.get("VAMOS_TOKEN", "")).value or None
            ca = p("ca_file", "").value
            self.profile = p("profile", "").value
            self.robot_id = p("robot_id", self.get_fully_qualified_name()).value
            self.session_id = p("session_id", "").value or f"{self.robot_id.strip('/').replace('/', '-')}-{uuid.uuid4().hex[:8]}"
            self.task = p("task", "").value
            image_topic = p("image_topic", "/camera/image_raw").value
            compressed = p("compressed", False).value
            info_topic = p("camera_info_topic", "/camera/camera_info").value
            joint_topics = p("joint_states_topics", ["/joint_states"]).value
            if not self.profile:
                raise SystemExit("parameter `profile` is required")
            root = open(ca, "rb").read() if ca else None
            self.client = MonitorClient(self.server, token=self.token, root_certificates=root)
            self.state = BridgeState()
            self.camera: Any = None
            self.session: Any = None
            # Joint states that came before the session opened (sent right after it opens,
            # so the first images can be interpolated).
            self.early_joints: "collections.deque[Any]" = collections.deque(maxlen=200)
            self.lock = threading.Lock()
            self.score_pub = self.create_publisher(Float64, p("score_topic", "/vamos/score").value, 10)
            self.anomaly_pub = self.create_publisher(Bool, p("anomaly_topic", "/vamos/anomaly").value, 10)
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_subscription(CompressedImage if compressed else Image, image_topic, self.on_image,
                                     qos_profile_sensor_data)
            self.create_subscription(RosCameraInfo, info_topic, self.on_info, qos_profile_sensor_data)
            for t in joint_topics:
                self.create_subscription(JointState, t, self.on_joints, qos_profile_sensor_data)
            self.create_timer(1.0, self.publish_diagnostics)
            self.get_logger().info(f"streaming {image_topic} + {joint_topics} to {self.server} "
                                   f"(profile {self.profile}, session {self.session_id})")

        def ensure_session(self) -> Any:
            with self.lock:
                if self.session is not None:
                    return self.session
                try:
                    s = self.client.open_session(self.profile, robot_id=self.robot_id,
                                                 session_id=self.session_id, task=self.task,
                                                 camera_info=self.camera)
                except SessionError as e:
                    self.state.connected = False
                    self.state.last_error = str(e)
                    self.get_logger().warning(f"cannot open the session: {e}")
                    return None
                self.state.on_update(s.opened)
                while self.early_joints:
                    s.send(self.early_joints.popleft())
                self.session = s
                threading.Thread(target=self.read, args=(s,), daemon=True).start()
                return s

        def read(self, s: Any) -> None:
            try:
                for u in s:
                    out = self.state.on_update(u)
                    if out is not None:
                        self.score_pub.publish(Float64(data=float(out[0])))
                        self.anomaly_pub.publish(Bool(data=bool(out[1])))
            except SessionError as e:
                self.state.last_error = str(e)
                self.get_logger().warning(f"stream ended: {e}; reconnecting at the next image")
            with self.lock:
                if self.session is s:
                    self.session = None
                    self.state.connected = False
                    self.state.reconnects += 1

        def send(self, request: Any) -> None:
            s = self.ensure_session()
            if s is not None:
                s.send(request)

        def on_info(self, msg: Any) -> None:
            if self.camera is None:
                try:
                    self.camera = camera_info(msg)
                except ValueError as e:
                    self.get_logger().warning(f"camera info ignored: {e}")

        def on_image(self, msg: Any) -> None:
            try:
                request = image_request(msg)
            except ValueError as e:
                self.state.refused += 1
                self.get_logger().warning(f"image ignored: {e}")
                return
            self.send(request)
            self.state.on_sent_image()

        def on_joints(self, msg: Any) -> None:
            request = joints_request(msg)
            with self.lock:
                if self.session is None:
                    self.early_joints.append(request)
                    return
            self.send(request)

        def publish_diagnostics(self) -> None:
            level, message, values = self.state.diagnostic()
            status = DiagnosticStatus(level=bytes([level]), name="vamos: anomaly monitor",
                                      message=message, hardware_id=self.robot_id,
                                      values=[KeyValue(key=k, value=v) for k, v in values])
            array = DiagnosticArray(status=[status])
            array.header.stamp = self.get_clock().now().to_msg()
            self.diag_pub.publish(array)

        def close(self) -> None:
            with self.lock:
                s, self.session = self.session, None
            if s is not None:
                s.finish()
                time.sleep(0.5)
            self.client.close()

    rclpy.init(args=argv)
    node = VamosBridge()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
