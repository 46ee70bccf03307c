"""Moved: the ROS 2 bridge is the ROS 2 package ``vamos_bridge`` (``clients/ros2`` in the
vamos repository: ``ros2 run vamos_bridge bridge``, ``ros2 launch vamos_bridge
bridge.launch.py``). What stays here is a thin shim: the ``vamos-ros-bridge`` command runs
that package's node when it is on the path, and :mod:`vamos.ros.convert` re-exports its
conversions.
"""
