"""A session driven from Python over gRPC against the real ``vamos serve``.

The raw generated stubs (``vamos.v1``) are used here, without the client library. A simulated episode (tests/fixtures/sim) is streamed message by message
as a robot would; the scores must equal those of ``vamos score`` for the same episode.

Needs ``VAMOS_BIN`` (``scripts/test.sh`` sets it); skipped without it.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess

from pathlib import Path

import pytest

grpc = pytest.importorskip("grpc")
mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

ROOT = Path(__file__).resolve().parents[3]
SIM = ROOT / "tests" / "fixtures" / "sim"
EPISODE = SIM / "test" / "test_0001_external_push.mcap"


@pytest.fixture(scope="module")
def vamos_bin() -> Path:
    value = os.environ.get("VAMOS_BIN")
    if not value:
        pytest.skip("VAMOS_BIN is not set (scripts/test.sh sets it)")
    path = Path(value)
    assert path.is_file(), f"VAMOS_BIN={value} does not exist"
    return path


@pytest.fixture(scope="module")
def stubs():
    # The committed stubs (src/vamos/v1, kept in step with the proto by test_client_stubs).
    from vamos.v1 import monitor_pb2, monitor_pb2_grpc

    return monitor_pb2, monitor_pb2_grpc


def _profile(tmp: Path) -> Path:
    path = tmp / "sim-arm.toml"
    path.write_text(
        f'name = "sim-arm"\n'
        f'robot = "{SIM / "robot" / "vamos_arm.urdf"}"\n'
        f'camera = "{SIM / "camera.json"}"\n'
        'flow_preset = "realtime"\n'
        "[pipeline]\nstride = 1\n"
        '[pipeline.frames]\nwidth = 160\nheight = 120\nvariant = "masked"\n'
    )
    return path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _requests(pb, session_id: str):
    with open(EPISODE, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        messages = list(reader.iter_decoded_messages(log_time_order=True))
    camera = None
    body = []
    for schema, _channel, _message, m in messages:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec if hasattr(m, "header") else 0
        if schema.name == "sensor_msgs/msg/Image":
            body.append(pb.StreamRequest(image=pb.Image(
                stamp_ns=stamp, encoding=m.encoding, width=m.width, height=m.height,
                step=m.step, big_endian=bool(m.is_bigendian), data=bytes(m.data))))
        elif schema.name == "sensor_msgs/msg/JointState":
            body.append(pb.StreamRequest(joints=pb.JointState(
                stamp_ns=stamp, names=list(m.name), positions=list(m.position),
                velocities=list(m.velocity), efforts=list(m.effort))))
        elif schema.name == "sensor_msgs/msg/CameraInfo" and camera is None:
            k = list(m.k)
            camera = pb.CameraInfo(width=m.width, height=m.height, fx=k[0], fy=k[4], cx=k[2], cy=k[5])
    open_msg = pb.StreamRequest(open=pb.OpenSession(
        robot_id="py-robot", profile="sim-arm", camera_info=camera, task="place_book",
        session_id=session_id))
    return [open_msg] + body


def test_python_session_matches_offline_scores(vamos_bin: Path, stubs, tmp_path: Path) -> None:
    pb, pb_grpc = stubs
    profile = _profile(tmp_path)
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    env["VAMOS_LOG__LEVEL"] = "warn"
    # The client sends as fast as it can: a queue that holds the whole episode, so no
    # image is dropped under backpressure (the default keeps 8).
    env["VAMOS_SERVICE__QUEUE_DEPTH"] = "64"

    # Offline scores of the same episode.
    out_dir = tmp_path / "offline"
    run = subprocess.run([str(vamos_bin), "score", "--profile", str(profile), str(EPISODE),
                          "--out", str(out_dir)], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    offline = [json.loads(line) for line in
               (out_dir / f"{EPISODE.stem}.scores.jsonl").read_text().splitlines()]
    assert len(offline) > 10

    grpc_port, rest_port = _free_port(), _free_port()
    server = subprocess.Popen(
        [str(vamos_bin), "serve", "--profile", str(profile), "--data-dir", str(tmp_path / "data"),
         "--grpc-addr", f"127.0.0.1:{grpc_port}", "--rest-addr", f"127.0.0.1:{rest_port}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        channel = grpc.insecure_channel(f"127.0.0.1:{grpc_port}")
        grpc.channel_ready_future(channel).result(timeout=30)
        stub = pb_grpc.MonitorStub(channel)
        # The session id is the episode's name: it seeds the predictor as `vamos score` does.
        responses = list(stub.Stream(iter(_requests(pb, EPISODE.stem)), timeout=120))
        scores = [r.score for r in responses if r.WhichOneof("message") == "score"]
        events = [r.event for r in responses if r.WhichOneof("message") == "event"]
        assert events[0].kind == pb.SessionEvent.KIND_OPENED
        assert not [e for e in events if e.kind == pb.SessionEvent.KIND_MESSAGE_ERROR]
        assert len(scores) == len(offline)
        for s, o in zip(scores, offline):
            assert s.stamp_ns == o["stamp_ns"]
            assert s.score == o["score"]
            assert s.anomaly == o["anomaly"]
            assert (s.e_c if s.HasField("e_c") else None) == o["e_c"]
            assert (s.e_b if s.HasField("e_b") else None) == o["e_b"]

        # A bad first message: INVALID_ARGUMENT, the server stays up.
        with pytest.raises(grpc.RpcError) as err:
            list(stub.Stream(iter([pb.StreamRequest(phase=pb.PhaseMarker(phase="release"))]), timeout=30))
        assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
        channel.close()
    finally:
        server.terminate()
        try:
            _, stderr = server.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
            _, stderr = server.communicate()
    # SIGTERM: a graceful stop.
    assert server.returncode == 0, stderr.decode(errors="replace")
    assert b"panicked" not in stderr

