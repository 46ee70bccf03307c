"""The ROS 2 packages' files, checked without ROS: package.xml against the format 3
rules (REP 149: root, element order, required and unique elements, names, versions,
build types), the message definition, setup.py's wheel (entry point, installed data
files) and the launch file's references."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROS2 = Path(__file__).resolve().parents[2]
BRIDGE = ROS2 / "vamos_bridge"
MSGS = ROS2 / "vamos_msgs"
VAMOS_SRC = ROS2.parent / "python" / "src"

# REP 149 (package format 3): the children of <package>, in this order; each group may
# repeat where the schema allows.
ORDER = ["name", "version", "description", "maintainer", "license", "url", "author",
         "build_depend", "build_export_depend", "buildtool_depend", "buildtool_export_depend", "exec_depend",
         "depend", "doc_depend", "test_depend", "conflict", "replace", "group_depend", "member_of_group", "export"]
DEPENDENCIES = {"build_depend", "build_export_depend", "buildtool_depend", "buildtool_export_depend", "exec_depend",
                "depend", "doc_depend", "test_depend", "conflict", "replace"}
ONCE = {"name", "version", "description", "export"}
REQUIRED = {"name", "version", "description", "maintainer", "license"}


def check_package_xml(path: Path) -> ET.Element:
    """Raises AssertionError naming the first broken rule."""
    text = path.read_text()
    assert text.startswith('<?xml version="1.0"?>'), "no XML declaration"
    assert 'href="http://download.ros.org/schema/package_format3.xsd"' in text, "no format 3 schema reference"
    root = ET.fromstring(text)
    assert root.tag == "package" and root.attrib == {"format": "3"}, "root must be <package format=\"3\">"
    tags = [child.tag for child in root]
    unknown = [t for t in tags if t not in ORDER]
    assert not unknown, f"unknown elements {unknown}"
    # Metadata first in the schema's order; dependencies after them in any order, then
    # group elements, then export.
    rank = {t: (i if t not in DEPENDENCIES else ORDER.index("build_depend")) for i, t in enumerate(ORDER)}
    ranks = [rank[t] for t in tags]
    assert ranks == sorted(ranks), f"elements out of the schema's order: {tags}"
    for tag in ONCE:
        assert tags.count(tag) <= 1, f"<{tag}> more than once"
    assert REQUIRED <= set(tags), f"missing {sorted(REQUIRED - set(tags))}"
    name = root.findtext("name")
    assert re.fullmatch(r"[a-z][a-z0-9_]*", name or ""), f"package name {name!r} (REP 144)"
    assert re.fullmatch(r"\d+\.\d+\.\d+", root.findtext("version") or ""), "version must be X.Y.Z"
    for m in root.findall("maintainer"):
        assert re.fullmatch(r"[^@\s]+@[^@\s]+\.[a-z]+", m.get("email", "")), "maintainer needs an email"
        assert (m.text or "").strip()
    for dep in (c for c in root if c.tag in DEPENDENCIES):
        assert re.fullmatch(r"[a-z][a-z0-9_\-]*", (dep.text or "").strip()), f"dependency {dep.text!r}"
        assert set(dep.attrib) <= {"version_lt", "version_lte", "version_eq", "version_gte", "version_gt",
                                   "condition"}
    deps = [(c.tag, c.text) for c in root if c.tag in DEPENDENCIES]
    assert len(deps) == len(set(deps)), "a dependency is listed twice"
    build_type = root.findtext("export/build_type")
    assert build_type in ("ament_python", "ament_cmake"), f"build_type {build_type!r}"
    assert ("buildtool_depend", build_type) in deps, f"{build_type} must be a buildtool_depend"
    return root


def test_package_xml_files_follow_format_3() -> None:
    bridge = check_package_xml(BRIDGE / "package.xml")
    msgs = check_package_xml(MSGS / "package.xml")
    assert bridge.findtext("export/build_type") == "ament_python"
    assert msgs.findtext("export/build_type") == "ament_cmake"
    # An interface package: generators at build time, the runtime and the group.
    assert ("rosidl_default_generators" in [e.text for e in msgs.findall("buildtool_depend")])
    assert msgs.findtext("member_of_group") == "rosidl_interface_packages"
    assert "rosidl_default_runtime" in [e.text for e in msgs.findall("exec_depend")]
    # The node imports these ROS packages; each is an exec_depend.
    node = (BRIDGE / "vamos_bridge" / "node.py").read_text()
    imported = set(re.findall(r"^\s+from (\w+)\.msg import", node, re.M)) | {"rclpy"}
    assert imported <= {e.text for e in bridge.findall("exec_depend")}, imported


@pytest.mark.parametrize("broken,rule", [
    ('<package format="2">', "format"),
    ("<name>Vamos-Bridge</name>", "REP 144"),
    ("<version>0.1</version>", "X.Y.Z"),
    ("<license>Apache-2.0</license>\n  <name>again</name>", "order"),
])
def test_the_package_xml_check_catches_broken_files(tmp_path: Path, broken: str, rule: str) -> None:
    text = (BRIDGE / "package.xml").read_text()
    good = {"format": '<package format="3">', "REP 144": "<name>vamos_bridge</name>",
            "X.Y.Z": "<version>0.1.0</version>", "order": "<license>Apache-2.0</license>"}[rule]
    assert good in text
    path = tmp_path / "package.xml"
    path.write_text(text.replace(good, broken, 1))
    with pytest.raises(AssertionError):
        check_package_xml(path)


@pytest.mark.parametrize("message", ["FrameScore", "AlarmEvent", "AlarmFrame"])
def test_the_message_definitions_build_with_rosidl_names(message: str) -> None:
    """Fields, constants and types as rosidl accepts them; every message and every
    package it uses in the CMakeLists and package.xml. (colcon builds them for real in
    clients/ros2/rclpy_wire, with ROS 2's wheels.)"""
    lines = [line.split("#", 1)[0].strip() for line in (MSGS / "msg" / f"{message}.msg").read_text().splitlines()]
    fields = [line.split() for line in lines if line and "=" not in line]
    constants = [line for line in lines if "=" in line]
    primitives = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
                  "uint32", "int64", "uint64", "string"}
    own = {p.stem for p in (MSGS / "msg").glob("*.msg")}
    cmake = (MSGS / "CMakeLists.txt").read_text()
    package = (MSGS / "package.xml").read_text()
    for kind, name in fields:
        base = kind.removesuffix("[]")
        assert base in primitives or base in own or re.fullmatch(r"[a-z][a-z0-9_]*/[A-Z][A-Za-z0-9]*", base), kind
        assert re.fullmatch(r"[a-z][a-z0-9_]*", name) and "__" not in name and not name.endswith("_"), name
        if "/" in base:
            dependency = base.split("/")[0]
            assert f"find_package({dependency} REQUIRED)" in cmake and f"<depend>{dependency}</depend>" in package
            assert re.search(rf"DEPENDENCIES[^)]*\b{dependency}\b", cmake), dependency
    for line in constants:
        assert re.fullmatch(r"(u?int(8|16|32|64)) [A-Z][A-Z0-9_]* *= *-?[0-9]+", line), line
    if message != "AlarmFrame":  # stamped messages: the header first
        assert fields[0] == ["std_msgs/Header", "header"]
    assert f'"msg/{message}.msg"' in cmake


def test_setup_py_installs_what_ros2_run_and_launch_look_for(tmp_path: Path) -> None:
    """The steps colcon's ament_python build runs (egg_info, build, install with
    setup.cfg's script folder), into a temporary root; then the installed ``bridge``
    script runs (and, without ROS here, says what it needs)."""
    pytest.importorskip("setuptools")
    run = subprocess.run([sys.executable, "setup.py", "-q", "egg_info", "--egg-base", str(tmp_path),
                          "build", "--build-base", str(tmp_path / "build"),
                          "install", "--root", str(tmp_path / "root"), "--prefix", "/opt/ws",
                          "--single-version-externally-managed", "--record", str(tmp_path / "files.txt")],
                         cwd=BRIDGE, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    installed = set((tmp_path / "files.txt").read_text().split())
    py = f"/opt/ws/lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages"
    assert {"/opt/ws/lib/vamos_bridge/bridge",  # where `ros2 run vamos_bridge bridge` looks
            "/opt/ws/share/ament_index/resource_index/packages/vamos_bridge",
            "/opt/ws/share/vamos_bridge/package.xml",
            "/opt/ws/share/vamos_bridge/launch/bridge.launch.py",
            "/opt/ws/share/vamos_bridge/config/vamos_bridge.yaml",
            *(f"{py}/vamos_bridge/{m}.py" for m in ("__init__", "bridge", "convert", "node", "params"))} <= installed
    root = tmp_path / "root"
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": f"{root}{py}:{VAMOS_SRC}"}
    script = subprocess.run([sys.executable, str(root / "opt/ws/lib/vamos_bridge/bridge")], capture_output=True,
                            text=True, env=env, timeout=60)
    try:
        import rclpy  # noqa: F401
    except ImportError:
        assert script.returncode == 2, script.stderr
        assert "needs a sourced ROS 2 workspace" in script.stderr and "Traceback" not in script.stderr
    else:  # pragma: no cover - only where ROS 2 is sourced
        pytest.skip("ROS 2 is installed here: the node would run")


def test_the_launch_file_runs_this_package_node_in_the_namespace() -> None:
    tree = ast.parse((BRIDGE / "launch" / "bridge.launch.py").read_text())
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    calls = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            calls.setdefault(node.func.id, []).append(node)
    (bridge_node,) = calls["Node"]
    kw = {k.arg: k.value for k in bridge_node.keywords}
    assert ast.literal_eval(kw["package"]) == "vamos_bridge" and ast.literal_eval(kw["executable"]) == "bridge"
    assert ast.unparse(kw["namespace"]) == "LaunchConfiguration('namespace')"
    declared = {ast.literal_eval(c.args[0]) for c in calls["DeclareLaunchArgument"]}
    assert declared == {"namespace", "params_file", "profile", "server", "depth_topic"}
    share = [ast.literal_eval(e) for c in calls["PathJoinSubstitution"] for e in c.args[0].elts[1:]]
    assert (BRIDGE.joinpath(*share)).is_file()  # config/vamos_bridge.yaml, installed by setup.py
