"""Start the real ``vamos serve`` for the end-to-end tests.

Shared by ``test_client_e2e.py`` and ``test_rest_fuzz.py``. It uses only the standard
library, so a test that needs nothing but HTTP does not depend on the gRPC client.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[3]
SIM = ROOT / "tests" / "fixtures" / "sim"
ADMIN, ROBOT = "py-admin-token", "py-robot-token"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def vamos_bin() -> Path:
    """The server binary named by ``VAMOS_BIN``; skips the calling test when it is unset."""
    value = os.environ.get("VAMOS_BIN")
    if not value:
        pytest.skip("VAMOS_BIN is not set (scripts/test.sh sets it)")
    return Path(value)


class Server:
    """``vamos serve`` with the ``sim-arm`` profile, admin and robot tokens, on free ports.
    ``profile_keys`` (top-level keys, e.g. ``model = "..."``) go before the profile's
    tables, ``profile_extra`` (tables, e.g. ``[thresholds]``) after them. ``grpc_port``: a
    port chosen beforehand (a client started before the server), else a free one.

    The constructor returns once ``GET /readyz`` answers ready (or fails the test when
    the process exits or 60 s pass). The server's stderr goes to a file in ``tmp`` so a
    chatty server can never block on a full pipe.
    """

    def __init__(self, bin: Path, tmp: Path, env: "dict[str, str] | None" = None,
                 profile_keys: str = "", profile_extra: str = "", grpc_port: "int | None" = None) -> None:
        self.bin, self.tmp = bin, tmp
        tmp.mkdir(parents=True, exist_ok=True)
        self.profile = tmp / "sim-arm.toml"
        self.profile.write_text(
            f'name = "sim-arm"\nrobot = "{SIM / "robot" / "vamos_arm.urdf"}"\n'
            f'camera = "{SIM / "camera.json"}"\nflow_preset = "realtime"\n' + profile_keys +
            '[pipeline]\nstride = 1\n[pipeline.frames]\nwidth = 160\nheight = 120\nvariant = "masked"\n'
            + profile_extra)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
        self.env.update(VAMOS_LOG__LEVEL="warn", VAMOS_ADMIN_TOKEN=ADMIN, VAMOS_ROBOT_TOKEN=ROBOT)
        self.env.update(env or {})
        self.grpc_port, self.rest_port = grpc_port or free_port(), free_port()
        self.grpc = f"127.0.0.1:{self.grpc_port}"
        self.rest = f"http://127.0.0.1:{self.rest_port}"
        self.stderr_path = tmp / "server.stderr"
        with self.stderr_path.open("wb") as stderr:
            self.proc = subprocess.Popen(
                [str(bin), "serve", "--profile", str(self.profile), "--data-dir", str(tmp / "data"),
                 "--grpc-addr", self.grpc, "--rest-addr", f"127.0.0.1:{self.rest_port}"],
                stdout=subprocess.DEVNULL, stderr=stderr, env=self.env)
        deadline = time.monotonic() + 60
        while not self.ready():
            assert self.proc.poll() is None, self.stderr()
            assert time.monotonic() < deadline, "the server did not become ready"
            time.sleep(0.1)

    def ready(self) -> bool:
        """Whether ``GET /readyz`` answers 200 ``{"status": "ready"}``."""
        try:
            with urllib.request.urlopen(f"{self.rest}/readyz", timeout=5) as r:
                return bool(r.status == 200 and json.loads(r.read()).get("status") == "ready")
        except (OSError, ValueError):
            # Refused while starting, a 503 (HTTPError is an OSError), or not JSON.
            return False

    def stderr(self) -> str:
        """What the server has written to stderr so far."""
        return self.stderr_path.read_text(errors="replace")

    def offline(self, episode: Path) -> list[dict[str, Any]]:
        """``vamos score`` of ``episode`` with the server's profile: one dict per frame."""
        out = self.tmp / f"offline-{episode.stem}"
        run = subprocess.run([str(self.bin), "score", "--profile", str(self.profile), str(episode),
                              "--out", str(out)], capture_output=True, text=True, env=self.env)
        assert run.returncode == 0, run.stderr
        return [json.loads(line) for line in (out / f"{episode.stem}.scores.jsonl").read_text().splitlines()]

    def stop(self) -> str:
        """SIGTERM (SIGKILL after 30 s); returns the server's stderr."""
        self.proc.terminate()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        return self.stderr()
