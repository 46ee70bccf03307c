"""vamos_bridge: a ROS 2 package (ament_python) that streams a robot's camera and joint
states to ``vamos serve`` and publishes the anomaly scores, stamped.

- :mod:`vamos_bridge.params`: the parameters and ROS 2 name resolution;
- :mod:`vamos_bridge.convert`: messages to vamos requests, scores to message fields;
- :mod:`vamos_bridge.bridge`: the session and its bookkeeping;
- :mod:`vamos_bridge.node`: the rclpy node (``ros2 run vamos_bridge bridge``).

Only :mod:`vamos_bridge.node` imports ROS; the rest needs the vamos Python client
(``pip install clients/python``) and is tested without ROS.
"""
