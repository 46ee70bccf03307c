"""The bridge's ROS parameters (one table: the node declares them from it, the YAML in
config/ sets them, the tests check both) and ROS 2 name resolution.

Topic names are relative by default, so they resolve under the node's namespace:
``ros2 launch vamos_bridge bridge.launch.py namespace:=robot1`` subscribes to
``/robot1/camera/image_raw`` and publishes ``/robot1/vamos/frame_score``, and several
robots share one graph. In the root namespace they resolve to ``/camera/image_raw`` and
``/vamos/score``, the names of the bridge before it was a ROS package.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

#: name -> (default, description). The default's type is the parameter's type.
PARAMETERS: dict[str, tuple[Any, str]] = {
    "server": ("127.0.0.1:8081", "vamos serve's gRPC address (host:port, or https://host:port for TLS)"),
    "token": ("", "bearer token of a robot (empty: $VAMOS_TOKEN)"),
    "ca_file": ("", "PEM CA certificate of a TLS server (empty: system roots)"),
    "profile": ("", "the server's profile to score with (required)"),
    "robot_id": ("", "the robot's name in the session (empty: from the node's namespace)"),
    "session_id": ("", "session id (empty: ROBOT_ID-<random>; a fixed one resumes after a reconnect)"),
    "task": ("", "task label recorded with the session"),
    "image_topic": ("camera/image_raw", "camera images (relative: under the node's namespace)"),
    "compressed": (False, "true: image_topic carries sensor_msgs/CompressedImage (JPEG/PNG)"),
    "depth_topic": ("", "sensor_msgs/Image depth registered to the images, 16UC1 mm or 32FC1 m (empty: none)"),
    "max_depth_gap_ms": (20.0, "an image takes the depth image nearest its stamp within this, ms; waits 2x this"),
    "camera_info_topic": ("camera/camera_info", "sensor_msgs/CameraInfo of the camera"),
    "joint_states_topics": (["joint_states"], "sensor_msgs/JointState topics"),
    "frame_score_topic": ("vamos/frame_score", "vamos_msgs/FrameScore, stamped with the image's header"),
    "score_topic": ("vamos/score", "std_msgs/Float64 score (unstamped; for plots)"),
    "anomaly_topic": ("vamos/anomaly", "std_msgs/Bool anomaly flag (unstamped)"),
    "alarm_topic": ("vamos/alarm", "vamos_msgs/AlarmEvent: each alarm's start and end, stamped with its image"),
    "anomaly_maps": (False, "true: ask vamos for each frame's anomaly map and publish it (costs bandwidth)"),
    "anomaly_map_topic": ("vamos/anomaly_map", "sensor_msgs/Image mono8 anomaly maps (with anomaly_maps)"),
    "diagnostics_period_s": (1.0, "period of the diagnostic_msgs/DiagnosticArray on /diagnostics, s"),
}


#: The largest ``max_depth_gap_ms``: farther apart, a depth image is of another moment.
MAX_DEPTH_GAP_MS = 1000.0


class ParameterError(ValueError):
    """A parameter value the bridge cannot run with."""


_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def validate_topic(name: str) -> str:
    """``name`` if it is a valid ROS 2 topic name (absolute, relative or private ``~``),
    else :class:`ParameterError`."""
    if not name:
        raise ParameterError("a topic name cannot be empty")
    if name == "~":
        return name
    if name.startswith("~") and not name.startswith("~/"):
        raise ParameterError(f"{name!r} is not a valid ROS 2 topic name (a private name starts with ~/)")
    body = name[2:] if name.startswith("~") else name[1:] if name.startswith("/") else name
    if body.endswith("/") or "//" in body or not all(_TOKEN.match(t) for t in body.split("/")):
        raise ParameterError(f"{name!r} is not a valid ROS 2 topic name (tokens of letters, digits and _, "
                             "not starting with a digit, separated by single /)")
    return name


def resolve_topic(name: str, namespace: str, node_name: str) -> str:
    """The fully qualified name rcl gives ``name`` for a node ``node_name`` in
    ``namespace`` (no remapping): absolute names stay, ``~`` is the node's own
    name, relative names go under the namespace."""
    validate_topic(name)
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        rest = name[1:].lstrip("/")
        return f"{ns}/{node_name}" + (f"/{rest}" if rest else "")
    return f"{ns}/{name}"


def default_robot_id(namespace: str, node_name: str) -> str:
    """The robot's name when ``robot_id`` is empty: the namespace (``/robot1`` ->
    ``robot1``, ``/fleet/arm_3`` -> ``fleet-arm_3``), or the node's name in the root
    namespace."""
    ns = namespace.strip("/")
    return ns.replace("/", "-") if ns else node_name


@dataclass(frozen=True)
class Params:
    """The parameters' values, checked."""

    server: str
    token: Optional[str]
    ca_file: str
    profile: str
    robot_id: str
    session_id: str
    task: str
    image_topic: str
    compressed: bool
    depth_topic: str
    max_depth_gap_ms: float
    camera_info_topic: str
    joint_states_topics: tuple[str, ...]
    frame_score_topic: str
    score_topic: str
    anomaly_topic: str
    alarm_topic: str
    anomaly_maps: bool
    anomaly_map_topic: str
    diagnostics_period_s: float
    resolved: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_values(cls, values: Mapping[str, Any], namespace: str, node_name: str, *,
                    env_token: Optional[str] = None, suffix: str = "") -> "Params":
        """Checks ``values`` (missing names take their defaults); ``suffix`` makes the
        default session id unique (the node passes a random one)."""
        unknown = sorted(set(values) - set(PARAMETERS))
        if unknown:
            raise ParameterError(f"unknown parameter(s) {unknown}")
        v = {k: values.get(k, default) for k, (default, _) in PARAMETERS.items()}
        for k, (default, _) in PARAMETERS.items():
            ok = isinstance(v[k], type(default)) or (isinstance(default, float) and isinstance(v[k], int))
            if not ok or (isinstance(default, list) and not all(isinstance(t, str) for t in v[k])):
                raise ParameterError(f"parameter {k} must be a {type(default).__name__}, got {v[k]!r}")
        if not v["profile"]:
            raise ParameterError("parameter `profile` is required (the server's profile to score with)")
        if not v["joint_states_topics"]:
            raise ParameterError("parameter `joint_states_topics` needs at least one topic")
        if not float(v["diagnostics_period_s"]) > 0:
            raise ParameterError("parameter `diagnostics_period_s` must be > 0")
        if not 0 < float(v["max_depth_gap_ms"]) <= MAX_DEPTH_GAP_MS:
            raise ParameterError(f"parameter `max_depth_gap_ms` must be > 0 and at most {MAX_DEPTH_GAP_MS:g}")
        topics = {k: v[k] for k in ("image_topic", "camera_info_topic", "frame_score_topic", "score_topic",
                                    "anomaly_topic", "alarm_topic")}
        if v["depth_topic"]:
            topics["depth_topic"] = v["depth_topic"]
        if v["anomaly_maps"]:
            topics["anomaly_map_topic"] = v["anomaly_map_topic"]
        topics.update({f"joint_states_topics[{i}]": t for i, t in enumerate(v["joint_states_topics"])})
        resolved = {k: resolve_topic(t, namespace, node_name) for k, t in topics.items()}
        robot_id = v["robot_id"] or default_robot_id(namespace, node_name)
        session_id = v["session_id"] or (f"{robot_id}-{suffix}" if suffix else robot_id)
        return cls(server=v["server"], token=v["token"] or env_token or None, ca_file=v["ca_file"],
                   profile=v["profile"], robot_id=robot_id, session_id=session_id, task=v["task"],
                   image_topic=v["image_topic"], compressed=v["compressed"], depth_topic=v["depth_topic"],
                   max_depth_gap_ms=float(v["max_depth_gap_ms"]),
                   camera_info_topic=v["camera_info_topic"], joint_states_topics=tuple(v["joint_states_topics"]),
                   frame_score_topic=v["frame_score_topic"], score_topic=v["score_topic"],
                   anomaly_topic=v["anomaly_topic"], alarm_topic=v["alarm_topic"], anomaly_maps=v["anomaly_maps"],
                   anomaly_map_topic=v["anomaly_map_topic"], diagnostics_period_s=float(v["diagnostics_period_s"]),
                   resolved=resolved)
