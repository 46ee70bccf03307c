"""Parameters, topic naming under namespaces, and the parameters YAML."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from vamos_bridge.params import PARAMETERS, ParameterError, Params, default_robot_id, resolve_topic, validate_topic

PACKAGE = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name,ns,node,resolved", [
    ("camera/image_raw", "/robot1", "vamos_bridge", "/robot1/camera/image_raw"),
    ("camera/image_raw", "/", "vamos_bridge", "/camera/image_raw"),
    ("camera/image_raw", "", "vamos_bridge", "/camera/image_raw"),
    ("vamos/score", "/fleet/arm_3/", "vamos_bridge", "/fleet/arm_3/vamos/score"),
    ("/diagnostics", "/robot1", "vamos_bridge", "/diagnostics"),
    ("~/status", "/robot1", "vamos_bridge", "/robot1/vamos_bridge/status"),
    ("~", "/robot1", "vamos_bridge", "/robot1/vamos_bridge"),
])
def test_topic_names_resolve_under_the_namespace(name: str, ns: str, node: str, resolved: str) -> None:
    assert resolve_topic(name, ns, node) == resolved


@pytest.mark.parametrize("bad", ["", "/", "a//b", "a/", "1camera", "camera/image raw", "cam-era", "~x"])
def test_invalid_topic_names_are_refused(bad: str) -> None:
    with pytest.raises(ParameterError):
        validate_topic(bad)


def test_two_robots_on_one_graph_do_not_collide() -> None:
    a = Params.from_values({"profile": "p"}, "/robot1", "vamos_bridge", suffix="x")
    b = Params.from_values({"profile": "p"}, "/robot2", "vamos_bridge", suffix="y")
    assert set(a.resolved.values()).isdisjoint(b.resolved.values())
    assert a.resolved["frame_score_topic"] == "/robot1/vamos/frame_score"
    assert a.resolved["alarm_topic"] == "/robot1/vamos/alarm"
    assert "anomaly_map_topic" not in a.resolved, "maps are off by default"
    assert b.resolved["joint_states_topics[0]"] == "/robot2/joint_states"
    assert (a.robot_id, a.session_id, b.robot_id, b.session_id) == ("robot1", "robot1-x", "robot2", "robot2-y")
    # In the root namespace the names are the old bridge's absolute ones.
    root = Params.from_values({"profile": "p"}, "/", "vamos_bridge")
    assert (root.resolved["score_topic"], root.resolved["anomaly_topic"], root.resolved["image_topic"]) == (
        "/vamos/score", "/vamos/anomaly", "/camera/image_raw")
    assert default_robot_id("/", "vamos_bridge") == "vamos_bridge"
    assert default_robot_id("/fleet/arm_3", "n") == "fleet-arm_3"


def test_parameter_values_are_checked() -> None:
    p = Params.from_values({"profile": "p", "robot_id": "arm", "session_id": "s1", "token": "",
                            "diagnostics_period_s": 2}, "/r", "n", env_token="from-env")
    assert (p.robot_id, p.session_id, p.token, p.diagnostics_period_s) == ("arm", "s1", "from-env", 2.0)
    with pytest.raises(ParameterError, match="`profile` is required"):
        Params.from_values({}, "/r", "n")
    with pytest.raises(ParameterError, match="unknown parameter"):
        Params.from_values({"profile": "p", "image_topics": ["x"]}, "/r", "n")
    with pytest.raises(ParameterError, match="compressed must be a bool"):
        Params.from_values({"profile": "p", "compressed": "yes"}, "/r", "n")
    with pytest.raises(ParameterError, match="at least one"):
        Params.from_values({"profile": "p", "joint_states_topics": []}, "/r", "n")
    with pytest.raises(ParameterError, match="> 0"):
        Params.from_values({"profile": "p", "diagnostics_period_s": 0.0}, "/r", "n")
    with pytest.raises(ParameterError, match="not a valid ROS 2 topic name"):
        Params.from_values({"profile": "p", "image_topic": "camera//image"}, "/r", "n")


def test_a_depth_topic_is_off_by_default_and_resolved_when_set() -> None:
    p = Params.from_values({"profile": "p"}, "/robot1", "vamos_bridge")
    assert (p.depth_topic, p.max_depth_gap_ms) == ("", 20.0)
    assert "depth_topic" not in p.resolved
    p = Params.from_values({"profile": "p", "depth_topic": "camera/aligned_depth_to_color/image_raw",
                            "max_depth_gap_ms": 15}, "/robot1", "vamos_bridge")
    assert p.resolved["depth_topic"] == "/robot1/camera/aligned_depth_to_color/image_raw"
    assert p.max_depth_gap_ms == 15.0
    with pytest.raises(ParameterError, match="not a valid ROS 2 topic name"):
        Params.from_values({"profile": "p", "depth_topic": "depth//image"}, "/r", "n")
    for bad in (0.0, -1.0, float("nan"), float("inf"), 1000.5):
        with pytest.raises(ParameterError, match="max_depth_gap_ms"):
            Params.from_values({"profile": "p", "max_depth_gap_ms": bad}, "/r", "n")
    with pytest.raises(ParameterError, match="depth_topic must be a str"):
        Params.from_values({"profile": "p", "depth_topic": 3}, "/r", "n")


def test_the_parameters_yaml_sets_every_parameter_with_its_type() -> None:
    doc = yaml.safe_load((PACKAGE / "config" / "vamos_bridge.yaml").read_text())
    assert list(doc) == ["/**"] and list(doc["/**"]) == ["ros__parameters"]
    values = doc["/**"]["ros__parameters"]
    assert list(values) == list(PARAMETERS)
    for name, (default, description) in PARAMETERS.items():
        assert type(values[name]) is type(default), name
        assert values[name] == default, name  # the file documents the defaults
        assert description
    # The file's values run once a profile is given (the launch file's `profile:=`).
    assert Params.from_values({**values, "profile": "p"}, "/robot1", "vamos_bridge").image_topic == "camera/image_raw"
