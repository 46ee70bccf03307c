"""Simulated robot episodes for vamos (pybullet): a robot arm places a book on a shelf.

``vamos-sim generate`` (:mod:`vamos.sim.cli`) writes ROS 2 bags in MCAP with frame labels.
Modules: :mod:`~vamos.sim.robot` (the URDF), :mod:`~vamos.sim.textures` (procedural
textures), :mod:`~vamos.sim.episode` (scene, task, anomalies), :mod:`~vamos.sim.bag`
(MCAP writing). Needs the ``sim`` extra: pybullet, numpy, tqdm, mcap, mcap-ros2-support.
"""
