"""The pip package's ``vamos.ros`` is a shim over the ROS 2 package ``vamos_bridge``
(clients/ros2/vamos_bridge, tested there): the same functions when that package is on
the path, and ``vamos-ros-bridge`` saying where the bridge went when it is not."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("grpc")

SRC = Path(__file__).resolve().parents[1] / "src"
BRIDGE = Path(__file__).resolve().parents[2] / "ros2" / "vamos_bridge"


def _run(code: str, *paths: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={"PYTHONPATH": ":".join(str(p) for p in (SRC, *paths))})


def test_the_shim_re_exports_the_ros_package() -> None:
    run = _run("import vamos.ros.convert as a, vamos_bridge.convert as b, vamos_bridge.bridge as c; "
               "assert a.image_request is b.image_request and a.BridgeState is c.BridgeState; print('same')", BRIDGE)
    assert run.returncode == 0, run.stderr
    assert run.stdout == "same\n"


def test_without_the_ros_package_the_shim_says_where_it_went() -> None:
    run = _run("import vamos.ros.convert")
    assert run.returncode == 1 and "moved to the ROS 2 package vamos_bridge" in run.stderr
    node = _run("from vamos.ros.node import main; raise SystemExit(main())")
    assert node.returncode == 2 and node.stdout == ""
    assert node.stderr.startswith("vamos-ros-bridge: the ROS 2 bridge is the ROS package vamos_bridge")
    assert "ros2 run vamos_bridge bridge" in node.stderr and node.stderr.count("\n") == 1
    version = _run("from vamos.ros.node import main; raise SystemExit(main(['--version']))")
    assert (version.returncode, version.stdout) == (0, f"vamos-ros-bridge {__import__('vamos').__version__}\n")


def test_with_the_ros_package_but_no_ros_the_node_says_what_it_needs() -> None:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        pass
    else:  # pragma: no cover - only where ROS 2 is sourced
        pytest.skip("ROS 2 is installed here; the node runs for real")
    run = _run("from vamos.ros.node import main; raise SystemExit(main())", BRIDGE)
    assert run.returncode == 2
    assert "needs a sourced ROS 2 workspace" in run.stderr
