#!/usr/bin/env bash
# The Python side of a ROS 2 distribution, without ROS: a virtual environment on the
# distribution's Python with its protobuf installed first (as python3-protobuf is on a
# ROS machine), then `pip install clients/python` (which must keep that protobuf), then
# the ROS package's tests and the client's stub tests on it.
#
#   clients/ros2/tools/distro_python.sh python3.10 3.12.4    # Humble: Ubuntu 22.04
#   clients/ros2/tools/distro_python.sh python3.12 4.21.12   # Jazzy: Ubuntu 24.04 (python3-protobuf 3.21.12)
#
# VAMOS_BIN (optional) adds the test that feeds a recorded robot through the bridge to
# the real server.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../../.."
PY="$1"; PROTOBUF="$2"
ENV="$(mktemp -d)/venv"
"$PY" -m venv "$ENV"
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1
"$ENV/bin/python" -m pip install --quiet "protobuf==$PROTOBUF" six
"$ENV/bin/python" -m pip install --quiet ./clients/python pytest pyyaml setuptools
"$ENV/bin/python" - "$PROTOBUF" <<'PYEOF'
import sys, google.protobuf
assert google.protobuf.__version__ == sys.argv[1], f"pip replaced protobuf {sys.argv[1]} with {google.protobuf.__version__}"
print(f"python {sys.version.split()[0]}, protobuf {google.protobuf.__version__} kept")
PYEOF
"$ENV/bin/python" -m pytest -q clients/ros2/vamos_bridge
"$ENV/bin/python" -m pytest -q -p no:cacheprovider --noconftest clients/python/tests/test_ros_convert.py \
    clients/python/tests/test_admin_client.py
rm -rf "$(dirname "$ENV")"
