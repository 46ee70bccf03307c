"""ament_python build of vamos_bridge (colcon build; ros2 run vamos_bridge bridge).

The vamos Python client it imports is not a ROS package: install it into the same
Python with ``pip install <vamos>/clients/python`` (it keeps the distribution's protobuf,
see clients/ros2/README.md).
"""

from glob import glob

from setuptools import setup

PACKAGE = "vamos_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[PACKAGE],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vamos maintainers",
    maintainer_email="vamos@users.noreply.github.com",
    description="Streams a robot's camera and joint states to vamos and publishes stamped anomaly scores",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": ["bridge = vamos_bridge.node:main"]},
)
