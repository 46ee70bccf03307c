"""The gRPC stubs import and encode the same bytes on the protobuf of the oldest
supported ROS 2 distributions.

- 3.12.4: Ubuntu 22.04's ``python3-protobuf`` (ROS 2 Humble), the floor in pyproject.toml;
  pure Python (PyPI's py2.py3 wheel installs on any Python 3).
- 3.20.3: the last 3.x, the first with the builder the stubs use when it is there.
- 4.21.12: the Python API of Ubuntu 24.04's ``python3-protobuf`` 3.21.12 (ROS 2 Jazzy;
  Debian numbers the package after the C++ release), with PyPI's upb back end.

Each version goes into a folder with ``pip install --target`` (small wheels; needs the
package index, like scripts/test.sh; ``VAMOS_SKIP_PIP_TESTS=1`` skips), put first on
``PYTHONPATH`` in a subprocess, which prints the encodings of a set of messages; they
must equal the current runtime's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("grpc")

SRC = Path(__file__).resolve().parents[1] / "src"

if os.environ.get("VAMOS_SKIP_PIP_TESTS") == "1":
    pytest.skip("VAMOS_SKIP_PIP_TESTS=1", allow_module_level=True)

PROBE = r"""
import json, sys
import google.protobuf
from vamos.v1 import monitor_pb2 as pb
from vamos.v1 import monitor_pb2_grpc  # the service stubs import too

out = {"version": google.protobuf.__version__, "file": pb.__file__, "protobuf_file": google.protobuf.__file__}
msgs = {
    "open": pb.StreamRequest(open=pb.OpenSession(robot_id="arm-3", profile="p", session_id="s-1", task="shelf",
                                                 camera_info=pb.CameraInfo(width=640, height=480, fx=500.0,
                                                                           fy=505.0, cx=320.0, cy=240.0))),
    "image": pb.StreamRequest(image=pb.Image(stamp_ns=3_000_000_500, encoding="rgb8", width=3, height=2, step=9,
                                             data=bytes(range(18)))),
    "joints": pb.StreamRequest(joints=pb.JointState(stamp_ns=-5, names=["a", "b"], positions=[0.1, -0.2],
                                                    efforts=[1.0, 2.0])),
    "score": pb.StreamResponse(score=pb.FrameScore(stamp_ns=7, index=2, frame=3, score=1.5, e_c=0.0, e_r=2.5,
                                                   anomaly=True, detector=pb.DETECTOR_FLOW, latency_s=0.01)),
    "event": pb.StreamResponse(event=pb.SessionEvent(kind=pb.SessionEvent.KIND_RESUMED, session_id="s-1",
                                                     detail="x", count=4)),
    "chunk": pb.EpisodeChunk(profile="p", data=b"\x00\xff", name="ep"),
}
out["bytes"] = {k: m.SerializeToString().hex() for k, m in msgs.items()}
# Parsing back: oneofs, proto3 optional presence, enums by name.
score = pb.StreamResponse.FromString(msgs["score"].SerializeToString()).score
out["presence"] = [score.HasField(f) for f in ("e_c", "e_b", "e_o", "e_r")]
out["which"] = [pb.StreamRequest.FromString(msgs[k].SerializeToString()).WhichOneof("message")
                for k in ("open", "image", "joints")]
out["enums"] = [pb.Detector.Name(score.detector), pb.SessionEvent.Kind.Name(6), pb.DETECTOR_SCENE]
out["stub"] = sorted(n for n in ("MonitorStub", "MonitorServicer", "add_MonitorServicer_to_server")
                     if hasattr(monitor_pb2_grpc, n))
print(json.dumps(out))
"""


def _probe(env: dict[str, str]) -> dict:
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


@pytest.fixture(scope="module")
def reference() -> dict:
    return _probe({**os.environ, "PYTHONPATH": str(SRC)})


@pytest.mark.parametrize("version", ["3.12.4", "3.20.3", "4.21.12"])
def test_the_stubs_work_on_old_protobuf(version: str, reference: dict, tmp_path: Path) -> None:
    target = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-cache-dir",
                          "--disable-pip-version-check", "--target", str(target), f"protobuf=={version}",
                          # protobuf 3.x imports six (python3-six on Ubuntu); setuptools, its
                          # other declared dependency, is only tried.
                          *(["six"] if version.startswith("3.") else [])],
                         capture_output=True, text=True, timeout=600)
    assert pip.returncode == 0, pip.stderr
    got = _probe({**os.environ, "PYTHONPATH": f"{target}{os.pathsep}{SRC}"})
    assert got["version"] == version and got["protobuf_file"].startswith(str(target))
    assert got["file"].startswith(str(SRC))
    assert reference["version"] != version
    for key in ("bytes", "presence", "which", "enums", "stub"):
        assert got[key] == reference[key], key
    assert got["presence"] == [True, False, False, True]
    assert got["which"] == ["open", "image", "joints"]
    assert got["enums"] == ["DETECTOR_FLOW", "KIND_RESUMED", 4]
