"""The rclpy node: ``ros2 run vamos_bridge bridge`` (or ``ros2 launch vamos_bridge
bridge.launch.py``). It declares the parameters of :mod:`vamos_bridge.params`, subscribes
with the sensor-data QoS profile camera drivers publish with (best effort, keep last 5,
joint states keep last 100: compatible with reliable publishers too), and publishes:

- ``vamos/frame_score`` (``vamos_msgs/FrameScore``): every score, with the scored
  image's ``header`` (stamp and frame_id), so it can be synchronised with the images;
- ``vamos/score`` (``std_msgs/Float64``) and ``vamos/anomaly`` (``std_msgs/Bool``);
- ``vamos/alarm`` (``vamos_msgs/AlarmEvent``): each alarm's start and end, stamped with
  the image at which it happened; reliable and transient-local, keep last 10 (an alarm
  is two messages, rare next to the scores: a console that subscribes late with
  transient-local still gets the last five alarms' edges, and volatile subscriptions
  match too);
- with ``anomaly_maps`` (off by default; only then does the server send maps),
  ``vamos/anomaly_map`` (``sensor_msgs/Image``, ``mono8``, 0 = nominal) with the scored
  image's header;
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, the ROS convention's absolute
  name): session, counts, latest score and latency, the resolved topics; ERROR when not
  connected, STALE without images, WARN with drops.

With ``depth_topic`` set it also subscribes to that ``sensor_msgs/Image`` topic (same
QoS) and runs a timer at half ``max_depth_gap_ms`` that sends the images whose wait for a
depth image has ended (:mod:`vamos_bridge.depth`).

SIGINT and SIGTERM end the spin, then the session is finished and its last scores are
published before the context shuts down (rclpy's own signal handling, which would shut
the context down first, is not installed).

Everything but the rclpy wiring is in :mod:`vamos_bridge.bridge` (tested without ROS).
"""

from __future__ import annotations

import os
import signal
import sys
import uuid
from typing import Any, Optional


def main(args: Optional[list[str]] = None) -> int:
    try:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from rclpy.signals import SignalHandlerOptions
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
        from std_msgs.msg import Bool, Float64
        from vamos_msgs.msg import AlarmEvent, AlarmFrame, FrameScore
    except ImportError as e:
        print(f"vamos_bridge needs a sourced ROS 2 workspace with vamos_msgs built (rclpy, sensor_msgs, "
              f"std_msgs, diagnostic_msgs, vamos_msgs): {e}", file=sys.stderr)
        return 2
    try:
        from vamos.client import MonitorClient
    except ImportError as e:
        print(f"vamos_bridge needs the vamos Python client in this environment: pip install "
              f"<vamos>/clients/python ({e})", file=sys.stderr)
        return 2

    from .bridge import Bridge, CallbackOutputs
    from .params import PARAMETERS, ParameterError, Params

    class VamosBridge(Node):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__("vamos_bridge")
            values = {name: self.declare_parameter(name, default).value for name, (default, _) in PARAMETERS.items()}
            self.vamos_params = Params.from_values(values, self.get_namespace(), self.get_name(),
                                             env_token=os.environ.get("VAMOS_TOKEN"), suffix=uuid.uuid4().hex[:8])
            p = self.vamos_params
            root = open(p.ca_file, "rb").read() if p.ca_file else None
            self.client = MonitorClient(p.server, token=p.token, root_certificates=root)
            self.frame_score_pub = self.create_publisher(FrameScore, p.frame_score_topic, 10)
            self.score_pub = self.create_publisher(Float64, p.score_topic, 10)
            self.anomaly_pub = self.create_publisher(Bool, p.anomaly_topic, 10)
            alarm_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.alarm_pub = self.create_publisher(AlarmEvent, p.alarm_topic, alarm_qos)
            self.map_pub = self.create_publisher(Image, p.anomaly_map_topic, 10) if p.anomaly_maps else None
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.bridge = Bridge(p, self.client, CallbackOutputs(self.publish_score, self.log_from_bridge,
                                                                 self.publish_alarm, self.publish_map))
            # rclpy's executor takes the ready subscriptions in the order they were made:
            # camera info and joint states before the images, so the image that opens the
            # session finds the camera info that came with it, and joint states are sent
            # before an image that arrived after them.
            self.create_subscription(CameraInfo, p.camera_info_topic, self.bridge.on_camera_info,
                                     qos_profile_sensor_data)
            # Joint states come many to an image: keep last 100 (as `vamos bridge` does), so a
            # burst while the node is busy is not cut to the last 5.
            joints_qos = QoSProfile(depth=100, reliability=qos_profile_sensor_data.reliability,
                                    durability=qos_profile_sensor_data.durability)
            for topic in p.joint_states_topics:
                self.create_subscription(JointState, topic, self.bridge.on_joint_state, joints_qos)
            if p.depth_topic:
                self.create_subscription(Image, p.depth_topic, self.bridge.on_depth, qos_profile_sensor_data)
                self.create_timer(p.max_depth_gap_ms / 2000.0, self.bridge.release_due)
            self.create_subscription(CompressedImage if p.compressed else Image, p.image_topic,
                                     self.bridge.on_image, qos_profile_sensor_data)
            self.create_timer(p.diagnostics_period_s, self.publish_diagnostics)
            depth = (f" with depth from {p.resolved['depth_topic']} (within {p.max_depth_gap_ms:g} ms)"
                     if p.depth_topic else "")
            self.get_logger().info(f"streaming {p.resolved['image_topic']}{depth} and "
                                   f"{', '.join(p.joint_states_topics)} to {p.server} as robot {p.robot_id} "
                                   f"(profile {p.profile}, session {p.session_id})")

        # Outputs of the bridge (called from its reader thread; rclpy publishers are
        # thread-safe).
        def publish_score(self, fields: dict[str, Any]) -> None:
            (stamp, frame_id) = fields["header"]
            msg = FrameScore(**{k: v for k, v in fields.items() if k != "header"})
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp.sec, stamp.nanosec
            msg.header.frame_id = frame_id
            self.frame_score_pub.publish(msg)
            self.score_pub.publish(Float64(data=fields["score"]))
            self.anomaly_pub.publish(Bool(data=fields["anomaly"]))

        def publish_alarm(self, fields: dict[str, Any]) -> None:
            msg = AlarmEvent(**{k: v for k, v in fields.items() if k not in ("header", "start", "peak")})
            _set_header(msg.header, fields["header"])
            for name in ("start", "peak"):
                frame = dict(fields[name])
                stamp = frame.pop("stamp")
                value = AlarmFrame(**frame)
                value.stamp.sec, value.stamp.nanosec = stamp.sec, stamp.nanosec
                setattr(msg, name, value)
            self.alarm_pub.publish(msg)

        def publish_map(self, fields: dict[str, Any]) -> None:
            if self.map_pub is None:
                return
            msg = Image(**{k: v for k, v in fields.items() if k != "header"})
            _set_header(msg.header, fields["header"])
            self.map_pub.publish(msg)

        def log_from_bridge(self, level: str, text: str) -> None:
            (self.get_logger().warning if level == "warning" else self.get_logger().info)(text)

        def publish_diagnostics(self) -> None:
            level, message, values = self.bridge.diagnostic()
            status = DiagnosticStatus(level=bytes([level]), name=f"vamos: {self.get_fully_qualified_name()}",
                                      message=message, hardware_id=self.vamos_params.robot_id,
                                      values=[KeyValue(key=k, value=v) for k, v in values])
            array = DiagnosticArray(status=[status])
            array.header.stamp = self.get_clock().now().to_msg()
            self.diag_pub.publish(array)

        def close(self) -> None:
            self.bridge.close()
            self.client.close()

    def _set_header(header: Any, value: tuple[Any, str]) -> None:
        stamp, frame_id = value
        header.stamp.sec, header.stamp.nanosec = stamp.sec, stamp.nanosec
        header.frame_id = frame_id

    def _stop(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    # The context must outlive the spin: closing the bridge publishes the session's last
    # scores. So SIGINT and SIGTERM only end the spin (KeyboardInterrupt).
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    try:
        node = VamosBridge()
    except ParameterError as e:
        print(f"vamos_bridge: {e}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
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
