"""``vamos-ros-bridge``: runs the ``vamos_bridge`` ROS 2 package's node when it is on the
path (a sourced workspace where it was built); otherwise says where the bridge went."""

from __future__ import annotations

import sys
from typing import Optional


def main(argv: Optional[list[str]] = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args == ["--version"]:
        from vamos import __version__

        print(f"vamos-ros-bridge {__version__}")
        return 0
    try:
        from vamos_bridge.node import main as bridge_main
    except ImportError:
        print("vamos-ros-bridge: the ROS 2 bridge is the ROS package vamos_bridge (clients/ros2 in the vamos "
              "repository); build it with colcon in a sourced ROS 2 workspace and run `ros2 run vamos_bridge "
              "bridge` or `ros2 launch vamos_bridge bridge.launch.py`", file=sys.stderr)
        return 2
    return int(bridge_main(argv))  # rclpy reads its --ros-args from sys.argv when argv is None


if __name__ == "__main__":
    raise SystemExit(main())
