"""A ROS 2 bridge: subscribes to a robot's image, camera-info and joint-state topics,
streams them to ``vamos serve`` as one session, and publishes the scores.

- :mod:`vamos.ros.convert`: the message conversions and the bridge's bookkeeping, plain
  Python (tested without ROS).
- :mod:`vamos.ros.node`: the rclpy node (``vamos-ros-bridge``); imports rclpy, so it needs
  a sourced ROS 2 installation.
"""
