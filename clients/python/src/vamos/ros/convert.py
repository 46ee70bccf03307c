"""Moved to the ROS 2 package ``vamos_bridge`` (``vamos_bridge.convert`` and
``vamos_bridge.bridge``); re-exported here for code that imported it from the pip
package, when ``vamos_bridge`` is on the path."""

from __future__ import annotations

try:
    from vamos_bridge.bridge import ERROR, OK, STALE, WARN, BridgeState
    from vamos_bridge.convert import camera_info, image_request, joints_request
except ImportError as e:
    raise ImportError("vamos.ros.convert moved to the ROS 2 package vamos_bridge (clients/ros2/vamos_bridge): "
                      "build it in a ROS 2 workspace and source it, or put that folder on PYTHONPATH") from e

__all__ = ["ERROR", "OK", "STALE", "WARN", "BridgeState", "camera_info", "image_request", "joints_request"]
