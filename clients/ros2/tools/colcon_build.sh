#!/usr/bin/env bash
# Builds this folder's ROS 2 packages with colcon against ROS 2 (Kilted) installed from
# its `ros-*` wheels on PyPI into a virtual environment: no ROS distribution, no apt
# repository of ROS. The environment is the underlay (its prefix holds the wheels'
# share/, lib/ and include/ folders, as /opt/ros/<distro> would); it needs what
# clients/ros2/rclpy_wire/requirements.txt lists (colcon, ament_cmake, the rosidl
# generators, cmake), and the machine a C and C++ compiler and the Python headers
# (Debian: g++ python3-dev).
#
#   clients/ros2/tools/colcon_build.sh VENV WORKSPACE [PACKAGE...]   # default: vamos_msgs
#   . WORKSPACE/install/setup.sh                                     # then use it
#
# e.g. `clients/ros2/tools/colcon_build.sh .venv-ros target/ros2_ws` (scripts/test.sh).
# WORKSPACE gets colcon's build/, install/ and log/ folders; the sources stay here.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
if [ $# -lt 2 ]; then
    echo "usage: $0 VENV WORKSPACE [PACKAGE...]" >&2
    exit 2
fi
VENV="$(cd "$1" && pwd)"
mkdir -p "$2"
WS="$(cd "$2" && pwd)"
shift 2
PACKAGES=("$@")
[ ${#PACKAGES[@]} -gt 0 ] || PACKAGES=(vamos_msgs)

PY="$VENV/bin/python"
for tool in cc c++; do
    command -v "$tool" >/dev/null || { echo "error: no $tool: colcon builds C and C++ type support (Debian: apt-get install g++)" >&2; exit 1; }
done
"$PY" - <<'PYEOF' || { echo "error: no Python headers for $PY (Debian: apt-get install python3-dev)" >&2; exit 1; }
import os, sysconfig
raise SystemExit(0 if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)
PYEOF
[ -x "$VENV/bin/colcon" ] || { echo "error: no colcon in $VENV: pip install -r clients/ros2/rclpy_wire/requirements.txt" >&2; exit 1; }

# A build folder made from another checkout (the workspace kept while the sources moved:
# CMake refuses a cache of another source folder) is built afresh.
for pkg in "${PACKAGES[@]}"; do
    cache="$WS/build/$pkg/CMakeCache.txt"
    if [ -f "$cache" ] && ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$ROOT/clients/ros2/$pkg" "$cache"; then
        echo "$WS/build/$pkg was configured for another source folder: building it afresh"
        rm -rf "${WS:?}/build/$pkg"
    fi
done

# The environment's prefix is the only underlay; its bin/ brings colcon, cmake and the
# Python that the generators and the Python type support are built with.
export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
unset COLCON_PREFIX_PATH PYTHONPATH
colcon --log-base "$WS/log" build \
    --base-paths "$ROOT/clients/ros2" \
    --build-base "$WS/build" --install-base "$WS/install" \
    --packages-select "${PACKAGES[@]}" \
    --cmake-args -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF \
        -DCMAKE_PROJECT_INCLUDE="$ROOT/clients/ros2/tools/wheel_prefix.cmake"
