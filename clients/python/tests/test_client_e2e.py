"""``vamos.client`` and ``vamos-client`` against the real ``vamos serve``.

Needs ``VAMOS_BIN`` (``scripts/test.sh`` sets it); skipped without it.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest

pytest.importorskip("grpc")
pytest.importorskip("mcap_ros2.decoder")

from _server import ADMIN, ROBOT, ROOT, SIM, Server, vamos_bin  # noqa: E402
from vamos.client import (  # noqa: E402
    AdminClient,
    AsyncMonitorClient,
    BadRequest,
    EpisodeDamaged,
    Forbidden,
    FrameScore,
    MonitorClient,
    NotFound,
    SessionError,
    Unauthorized,
    read_episode,
)

EPISODE = SIM / "test" / "test_0001_external_push.mcap"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    s = Server(vamos_bin(), tmp_path_factory.mktemp("client-e2e"))
    yield s
    stderr = s.stop()
    assert s.proc.returncode == 0, stderr
    assert "panicked" not in stderr


def _same(scores: list[FrameScore], offline: list[dict]) -> None:
    assert len(scores) == len(offline) > 10
    for s, o in zip(scores, offline):
        assert (s.stamp_ns, s.score, s.anomaly, s.e_c, s.e_b) == (
            o["stamp_ns"], o["score"], o["anomaly"], o["e_c"], o["e_b"])


def test_replay_and_batch_scoring_equal_offline_scoring(server: Server, tmp_path: Path) -> None:
    offline = server.offline(EPISODE)
    seen = []
    with MonitorClient(server.grpc, token=ROBOT) as client:
        client.wait_ready()
        summary = client.replay(EPISODE, "sim-arm", rate=None, window=4, on_update=seen.append)
        assert summary.session_id == EPISODE.stem
        assert summary.dropped == 0 and not summary.message_errors
        assert summary.images_sent == read_episode(EPISODE).images
        assert summary.events[0].kind == "opened"
        assert len(seen) == len(summary.scores) + len(summary.events) + len(summary.alarms)
        _same(summary.scores, offline)
        _same(client.score_episode(EPISODE, "sim-arm"), offline)
        # A file cut short: the frames before the damage, then EpisodeDamaged.
        cut = tmp_path / "cut.mcap"
        data = EPISODE.read_bytes()
        cut.write_bytes(data[: len(data) * 2 // 3])
        with pytest.raises(EpisodeDamaged) as damaged:
            client.score_episode(cut, "sim-arm", name=EPISODE.stem)
        partial = damaged.value.scores
        assert 0 < len(partial) < len(offline)
        _same(partial, offline[: len(partial)])


def test_asyncio_session_fed_by_hand(server: Server) -> None:
    offline = server.offline(EPISODE)
    rec = read_episode(EPISODE)

    async def run() -> list[FrameScore]:
        async with AsyncMonitorClient(server.grpc, token=ROBOT) as client:
            session = await client.open_session("sim-arm", session_id=EPISODE.stem,
                                                camera_info=rec.camera)
            assert session.opened.kind == "opened"
            scores: list[FrameScore] = []

            async def read() -> None:
                async for u in session:
                    if isinstance(u, FrameScore):
                        scores.append(u)

            reader = asyncio.create_task(read())
            images = 0
            for _, m in rec.messages:
                if m.WhichOneof("message") == "image":
                    images += 1
                    # Stay under the server's queue of 8.
                    while images - len(scores) > 4 and not reader.done():
                        await asyncio.sleep(0.005)
                await session.send(m)
            await session.finish()
            await reader
            assert len(await client.score_episode(EPISODE, "sim-arm")) == len(offline)
            return scores

    _same(asyncio.run(run()), offline)


def test_recorded_pace_and_refusals(server: Server) -> None:
    rec = read_episode(EPISODE)
    span = rec.messages[-1][0] / 1e9
    with MonitorClient(server.grpc, token=ROBOT) as client:
        started = time.monotonic()
        summary = client.replay(rec, "sim-arm", rate=4.0, session_id="paced")
        assert time.monotonic() - started >= span / 4
        assert len(summary.scores) == rec.images
        with pytest.raises(SessionError) as e:
            client.open_session("no-such-profile")
        assert e.value.code == "NOT_FOUND"
    with MonitorClient(server.grpc) as anonymous, pytest.raises(SessionError) as e:
        anonymous.open_session("sim-arm")
    assert e.value.code == "UNAUTHENTICATED"


class Proxy:
    """A TCP forwarder whose connections can be cut."""

    def __init__(self, target_port: int) -> None:
        self.target_port = target_port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                a, _ = self.listener.accept()
            except OSError:
                return
            b = socket.create_connection(("127.0.0.1", self.target_port))
            with self.lock:
                self.conns += [a, b]
            for src, dst in ((a, b), (b, a)):
                threading.Thread(target=self._pump, args=(src, dst), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def cut(self) -> None:
        with self.lock:
            conns, self.conns = self.conns, []
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()


def test_a_broken_stream_is_resumed(server: Server) -> None:
    proxy = Proxy(server.grpc_port)
    rec = read_episode(EPISODE)
    cut_done = threading.Event()

    def on_update(u: object) -> None:
        if isinstance(u, FrameScore) and u.frame == 10 and not cut_done.is_set():
            cut_done.set()
            proxy.cut()

    with MonitorClient(f"127.0.0.1:{proxy.port}", token=ROBOT) as client:
        summary = client.replay(rec, "sim-arm", rate=2.0, session_id="resumable", on_update=on_update)
    assert cut_done.is_set()
    assert summary.reconnects == 1, summary.events
    assert summary.session_id == "resumable"
    assert [e.kind for e in summary.events].count("resumed") == 1
    # Scores carry on across the break with the session's own counters; at most the
    # images in flight when the stream broke are lost.
    # `frame` counts the images the session processed, so an image lost in flight lowers
    # the last one; the stamps say which images were scored: the last image must be.
    frames = [s.frame for s in summary.scores]
    assert frames == sorted(set(frames))
    image_stamps = [m.image.stamp_ns for _, m in rec.messages if m.WhichOneof("message") == "image"]
    assert summary.scores[-1].stamp_ns == image_stamps[-1]
    assert len(summary.scores) >= rec.images - 4


def test_admin_client_round_trip(server: Server, tmp_path: Path) -> None:
    admin = AdminClient(server.rest, token=ADMIN)
    assert admin.healthy() and admin.ready()
    robot = admin.upload_robot("arm", SIM / "robot" / "vamos_arm.urdf")
    assert robot["name"] == "arm" and robot["format"] == "urdf"
    model = admin.upload_model("tiny", ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos")
    assert (model["version"], model["active"]) == (1, 1)
    with pytest.raises(BadRequest):
        admin.upload_model("tiny", ROOT / "tests" / "fixtures" / "model" / "corrupt_onnx.vamos")
    camera = json.loads((SIM / "camera.json").read_text())
    spec = {"robot": "arm", "camera": camera, "model": {"name": "tiny"}, "flow_preset": "realtime",
            "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120, "variant": "masked"}}}
    assert admin.put_profile("arm-store", spec)["model"] == "tiny@1"
    job = admin.calibrate("arm-store", [SIM / "train" / "train_0000.mcap", SIM / "train" / "train_0001.mcap"],
                          alpha=0.2)
    done = admin.wait_job(job, timeout=600)
    assert done["calibration"]["training_episodes"] == ["train_0000", "train_0001"]
    assert done["episodes"] == ["train_0000.mcap", "train_0001.mcap"]
    assert admin.profile("arm-store")["calibrated"] is True
    assert admin.set_thresholds("arm-store", alarm=3.5)["alarm_threshold"] == 3.5
    assert admin.set_thresholds("arm-store", alarm=None)["alarm_threshold"] != 3.5
    assert any(j["id"] == job for j in admin.jobs())
    scored = admin.score_episode(EPISODE, "sim-arm")
    assert len(scored["frames"]) == len(server.offline(EPISODE)) and scored["damage"] is None
    assert "vamos_frames_processed_total" in admin.metrics()
    assert isinstance(admin.sessions(), list)
    store = admin.store_status()
    assert store["shared_store"] is None and store["read_only"] is None and store["problems"] == 0
    with pytest.raises(NotFound):
        admin.reload_session("nobody")
    with pytest.raises(NotFound):
        admin.model("nothing-here")
    with pytest.raises(Forbidden):
        AdminClient(server.rest, token=ROBOT).delete_model("tiny")
    with pytest.raises(Unauthorized):
        AdminClient(server.rest).models()


def _cli(server: Server, *args: str) -> subprocess.CompletedProcess:
    exe = shutil.which("vamos-client", path=str(Path(sys.executable).parent))
    cmd = [exe] if exe else [sys.executable, "-m", "vamos.client"]
    env = dict(os.environ, VAMOS_TOKEN=ADMIN, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "src"))
    return subprocess.run([*cmd, "--server", server.grpc, "--api", server.rest, *args],
                          capture_output=True, text=True, env=env, timeout=300)


def test_the_command_line(server: Server) -> None:
    offline = server.offline(EPISODE)
    run = _cli(server, "stream", str(EPISODE), "--profile", "sim-arm", "--fast")
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    scores = [(x["stamp_ns"], x["score"]) for x in lines if x["type"] == "score"]
    assert scores == [(o["stamp_ns"], o["score"]) for o in offline]
    assert f"{len(offline)} scored" in run.stderr
    run = _cli(server, "score", str(EPISODE), "--profile", "sim-arm")
    assert run.returncode == 0, run.stderr
    assert [json.loads(x)["score"] for x in run.stdout.splitlines()] == [o["score"] for o in offline]
    run = _cli(server, "profiles", "list")
    assert run.returncode == 0, run.stderr
    assert "sim-arm" in [p["name"] for p in json.loads(run.stdout)]
    run = _cli(server, "jobs", "12345")
    assert run.returncode == 1 and "HTTP 404" in run.stderr
    run = _cli(server, "thresholds", "sim-arm")
    assert run.returncode == 2
