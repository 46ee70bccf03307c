#!/usr/bin/env bash
# All of vamos's tests, with their set-up: the README's test command.
#  1. Rust: `cargo test --release --locked --workspace --features vamos/wgpu` (every crate's
#     unit, integration and doc tests;
#     the feature adds the GPU render back-end, whose tests compare it with the CPU one on
#     any wgpu adapter, Mesa's lavapipe on a GPU-less host, and say SKIPPED when there is
#     none unless VAMOS_REQUIRE_GPU_TESTS=1). The model tests load ONNX Runtime; when it is
#     not found (ORT_DYLIB_PATH, the vamos cache, Python's onnxruntime) vamos downloads the
#     PyPI wheel into its cache with pip.
#  2. Python (clients/python): a virtual environment in .venv with the package and its
#     `train` + `sim` + `test` extras (torch from PyPI: ~3 GB on the first run), then pytest,
#     including the end-to-end test that runs the Rust binary built in step 1; then the
#     ROS 2 tests: the Python ROS 2 package's (clients/ros2/vamos_bridge: no ROS needed, see
#     its README) and `vamos bridge` on the wire against Eclipse Cyclone DDS
#     (clients/ros2/dds_wire); then, from a second virtual environment (.venv-ros) with
#     ROS 2's own wheels, vamos_msgs and vamos_bridge built by colcon, and a real rclpy
#     node on Fast DDS against `vamos bridge` and the vamos_bridge node, reading the
#     generated vamos_msgs types (clients/ros2/rclpy_wire).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

echo "== Rust tests"
cargo test --release --locked --workspace --features vamos/wgpu

echo "== Python environment (.venv)"
# torch's wheels need ~10 GiB while they install (~3 GB downloaded, ~6.7 GB unpacked). On a
# short disk, the Rust build's intermediate artefacts (several GB, not used from here on)
# make room; the binary the Python tests run stays.
free_gib() { df -k --output=avail . | tail -1 | awk '{ print int($1 / 1048576) }'; }
if [ ! -x .venv/bin/python ] && [ "$(free_gib)" -lt 14 ] && [ -x target/release/vamos ]; then
    echo "only $(free_gib) GiB free: removing target/release's intermediate artefacts (target/release/vamos stays; the next cargo build starts over)"
    find target/release -mindepth 1 -maxdepth 1 ! -name vamos -exec rm -rf {} +
fi
echo "$(free_gib) GiB free for the Python environment"
PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    if ! "$PYTHON" -m venv .venv; then
        echo "error: cannot create a Python virtual environment; on Debian/Ubuntu install" >&2
        echo "       it with: sudo apt-get install python3-venv" >&2
        exit 1
    fi
fi
# No pip cache: the wheels would take another ~3 GB beside the installed packages.
export PIP_NO_CACHE_DIR=1
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet './clients/python[train,sim,client,test]'

echo "== Python tests"
VAMOS_BIN="$PWD/target/release/vamos" .venv/bin/python -m pytest clients/python/tests -q

echo "== ROS 2 tests (clients/ros2: the package without ROS; vamos bridge against Cyclone DDS)"
# Two runs: each folder has its own pytest configuration (vamos_bridge's setup.cfg).
VAMOS_BIN="$PWD/target/release/vamos" .venv/bin/python -m pytest clients/ros2/vamos_bridge -q
VAMOS_BIN="$PWD/target/release/vamos" .venv/bin/python -m pytest clients/ros2/dds_wire -q

echo "== ROS 2 itself (rclpy on Fast DDS, from the ROS 2 wheels on PyPI; its own environment, .venv-ros)"
if [ ! -x .venv-ros/bin/python ]; then
    "$PYTHON" -m venv .venv-ros
fi
.venv-ros/bin/python -m pip install --quiet --upgrade pip
.venv-ros/bin/python -m pip install --quiet -r clients/ros2/rclpy_wire/requirements.txt
# The Python bridge node's client (grpcio, protobuf... from PyPI).
.venv-ros/bin/python -m pip install --quiet ./clients/python
# vamos_msgs and vamos_bridge built by colcon against those wheels (~30 s; needs g++ and
# the Python headers), then the tests with the workspace sourced: rclpy reads vamos_msgs
# through the generated types, and the vamos_bridge node runs as colcon installed it.
clients/ros2/tools/colcon_build.sh .venv-ros target/ros2_ws vamos_msgs vamos_bridge
(
    set +u  # colcon's setup.sh reads variables that may be unset
    . target/ros2_ws/install/setup.sh
    set -u
    REQUIRE_VAMOS_MSGS=1 VAMOS_BIN="$PWD/target/release/vamos" \
        .venv-ros/bin/python -m pytest clients/ros2/rclpy_wire -q -p no:cacheprovider
)
