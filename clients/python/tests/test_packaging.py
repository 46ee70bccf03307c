"""``pip install clients/python`` with no extras, in a fresh virtual environment, gives
working commands: ``--version`` everywhere, ``vamos-client`` against the real server, a
one-line message naming the extra for ``vamos-sim`` and ``vamos-train``, and the asyncio
admin client round trip against the real ``vamos serve``.

Needs pip to reach the package index (as scripts/test.sh does); set
``VAMOS_SKIP_PIP_TESTS=1`` to skip where it cannot. The server tests need ``VAMOS_BIN``.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import venv
from pathlib import Path
from typing import Iterator

import pytest

from _server import ADMIN, ROBOT, ROOT, SIM, Server, vamos_bin
from vamos._cli import EXTRA_MODULES

PACKAGE = Path(__file__).resolve().parents[1]

if os.environ.get("VAMOS_SKIP_PIP_TESTS") == "1":
    pytest.skip("VAMOS_SKIP_PIP_TESTS=1", allow_module_level=True)


class Env:
    """A virtual environment with nothing but ``pip install clients/python``."""

    def __init__(self, root: Path) -> None:
        venv.EnvBuilder(with_pip=True).create(root)
        self.bin = root / "bin"
        self.python = self.bin / "python"
        # A clean environment: nothing from the test's own interpreter leaks in.
        self.env = {"PATH": f"{self.bin}:/usr/bin:/bin", "HOME": str(root), "PIP_NO_CACHE_DIR": "1",
                    "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
        pip = self.run(str(self.python), "-m", "pip", "install", "--quiet", str(PACKAGE), timeout=900)
        assert pip.returncode == 0, f"pip install clients/python failed:\n{pip.stdout}\n{pip.stderr}"

    def run(self, *cmd: str, timeout: float = 300, env: "dict[str, str] | None" = None,
            cwd: "Path | None" = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout,
                              env={**self.env, **(env or {})}, cwd=cwd)


@pytest.fixture(scope="module")
def fresh(tmp_path_factory: pytest.TempPathFactory) -> Env:
    return Env(tmp_path_factory.mktemp("fresh-venv") / "venv")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    s = Server(vamos_bin(), tmp_path_factory.mktemp("packaging-e2e"))
    yield s
    stderr = s.stop()
    assert s.proc.returncode == 0, stderr


def test_only_the_core_dependencies_are_installed(fresh: Env) -> None:
    probe = ("import importlib.util as u, json; print(json.dumps({m: u.find_spec(m) is not None for m in "
             "['vamos', 'grpc', 'google.protobuf', 'httpx', 'mcap', 'mcap_ros2', 'numpy', 'torch', 'pybullet']}))")
    run = fresh.run(str(fresh.python), "-c", probe, cwd=fresh.bin)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == {"vamos": True, "grpc": True, "google.protobuf": True, "httpx": True,
                                      "mcap": True, "mcap_ros2": True, "numpy": False, "torch": False,
                                      "pybullet": False}


@pytest.mark.parametrize("command", ["vamos-client", "vamos-sim", "vamos-train", "vamos-ros-bridge"])
def test_every_command_answers_version(fresh: Env, command: str) -> None:
    run = fresh.run(str(fresh.bin / command), "--version")
    assert (run.returncode, run.stderr) == (0, "")
    assert run.stdout == f"{command} 0.1.0\n"


@pytest.mark.parametrize("command,args,extra", [
    ("vamos-sim", ["generate", "--out", "x", "--smoke"], "sim"),
    ("vamos-train", ["export-random", "-o", "x.vamos"], "train"),
])
def test_a_missing_extra_is_one_line_naming_it(fresh: Env, tmp_path: Path, command: str, args: list[str],
                                               extra: str) -> None:
    run = fresh.run(str(fresh.bin / command), *args, cwd=tmp_path)
    assert run.returncode == 2 and run.stdout == ""
    found = re.fullmatch(rf"{command}: error: this command needs the '{extra}' dependencies \(module '(\w+)' is "
                         rf"not installed\): pip install 'vamos-client\[{extra}\]'\n", run.stderr)
    assert found is not None, run.stderr
    assert found.group(1) in EXTRA_MODULES[extra]
    assert not list(tmp_path.iterdir())  # nothing was written


def test_the_client_command_works_with_the_core_install(fresh: Env, server: Server) -> None:
    episode = SIM / "test" / "test_0001_external_push.mcap"
    run = fresh.run(str(fresh.bin / "vamos-client"), "--server", server.grpc, "--api", server.rest,
                    "score", str(episode), "--profile", "sim-arm", env={"VAMOS_TOKEN": ROBOT})
    assert run.returncode == 0, run.stderr
    scores = [json.loads(line)["score"] for line in run.stdout.splitlines()]
    assert scores == [o["score"] for o in server.offline(episode)]


ASYNC_SCRIPT = """
import asyncio, json, sys
from vamos.client import AsyncAdminClient, BadRequest, Forbidden, NotFound, Unauthorized

rest, admin_token, robot_token, sim, fixtures = sys.argv[1:6]

async def main():
    out = {}
    async with AsyncAdminClient(rest, token=admin_token) as admin:
        out["healthy"], out["ready"] = await admin.healthy(), await admin.ready()
        out["robot"] = (await admin.upload_robot("arm", sim + "/robot/vamos_arm.urdf"))["format"]
        m = await admin.upload_model("tiny", fixtures + "/model/tiny_trained.vamos")
        out["model"] = [m["version"], m["active"]]
        try:
            await admin.upload_model("tiny", fixtures + "/model/corrupt_onnx.vamos")
        except BadRequest as e:
            out["corrupt"] = e.status
        camera = json.load(open(sim + "/camera.json"))
        spec = {"robot": "arm", "camera": camera, "model": {"name": "tiny"}, "flow_preset": "realtime",
                "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120, "variant": "masked"}}}
        out["profile"] = (await admin.put_profile("arm-async", spec))["model"]
        job = await admin.calibrate("arm-async", [sim + "/train/train_0000.mcap"], alpha=0.2)
        done = await admin.wait_job(job, timeout=600)
        out["calibrated"] = [done["episodes"], (await admin.profile("arm-async"))["calibrated"]]
        out["alarm"] = (await admin.set_thresholds("arm-async", alarm=3.5))["alarm_threshold"]
        scored = await admin.score_episode(sim + "/test/test_0001_external_push.mcap", "sim-arm")
        out["scored"] = [len(scored["frames"]), scored["damage"]]
        out["models"] = sorted(x["name"] for x in await admin.models())
        out["metrics"] = "vamos_frames_processed_total" in await admin.metrics()
        try:
            await admin.model("nothing-here")
        except NotFound as e:
            out["not_found"] = e.status
    async with AsyncAdminClient(rest, token=robot_token) as robot:
        try:
            await robot.delete_model("tiny")
        except Forbidden as e:
            out["forbidden"] = e.status
    async with AsyncAdminClient(rest) as anonymous:
        try:
            await anonymous.models()
        except Unauthorized as e:
            out["unauthorized"] = e.status
    print(json.dumps(out))

asyncio.run(main())
"""


def test_the_async_admin_client_against_the_real_server(fresh: Env, server: Server, tmp_path: Path) -> None:
    script = tmp_path / "async_admin.py"
    script.write_text(ASYNC_SCRIPT)
    run = fresh.run(str(fresh.python), str(script), server.rest, ADMIN, ROBOT, str(SIM),
                    str(ROOT / "tests" / "fixtures"), timeout=900, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    frames = len(server.offline(SIM / "test" / "test_0001_external_push.mcap"))
    assert out == {
        "healthy": True, "ready": True, "robot": "urdf", "model": [1, 1], "corrupt": 400, "profile": "tiny@1",
        "calibrated": [["train_0000.mcap"], True], "alarm": 3.5, "scored": [frames, None], "models": ["tiny"],
        "metrics": True, "not_found": 404, "forbidden": 403, "unauthorized": 401,
    }
