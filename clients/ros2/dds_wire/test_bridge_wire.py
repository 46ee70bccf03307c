"""`vamos bridge` on the wire, against a second DDS implementation.

The bridge is a ROS 2 node written on RustDDS (ros2-client). Here Eclipse Cyclone DDS (the
`cyclonedds` wheel from PyPI, the default RMW of several ROS 2 distributions) plays the
robot: it publishes a recorded episode's `sensor_msgs` under the ROS 2 topic and type names
(`rt/robot1/camera/image_raw`, `sensor_msgs::msg::dds_::Image_`) and reads the bridge's
`vamos_msgs/FrameScore`, `std_msgs` and `diagnostic_msgs` outputs back. The scores must be
those `vamos score` gives the same bag with the same profile, each stamped with its
image's header.

Needs `VAMOS_BIN` (scripts/test.sh sets it) and the `cyclonedds` package (the `test`
extra of clients/python); skipped without them.
"""

from __future__ import annotations

import math
import os
import random
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import pytest

cyclonedds = pytest.importorskip("cyclonedds")
from cyclonedds.core import Qos, Policy  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "clients" / "python" / "tests"))

import ros2_types as ros  # noqa: E402
from _server import ROBOT, Server, vamos_bin  # noqa: E402

EPISODE = ROOT / "tests" / "fixtures" / "sim" / "test" / "test_0000.mcap"
RELIABLE = Qos(Policy.Reliability.Reliable(max_blocking_time=1_000_000_000), Policy.History.KeepLast(100))


def read_episode(path: Path) -> list[tuple[str, Any]]:
    """The bag's camera, camera info and joint state messages in log-time order, as the
    Cyclone types."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def header(m: Any) -> ros.Header:
        return ros.Header(ros.Time(m.header.stamp.sec, m.header.stamp.nanosec), m.header.frame_id)

    out: list[tuple[str, Any]] = []
    with path.open("rb") as f:
        for _schema, channel, _message, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic == "/camera/image_raw":
                out.append(("image", ros.Image(header(m), m.height, m.width, m.encoding, m.is_bigendian, m.step,
                                               list(m.data))))
            elif channel.topic == "/camera/camera_info":
                out.append(("camera_info", ros.CameraInfo(
                    header(m), m.height, m.width, m.distortion_model, list(m.d), list(m.k), list(m.r), list(m.p),
                    m.binning_x, m.binning_y, ros.RegionOfInterest(m.roi.x_offset, m.roi.y_offset, m.roi.height,
                                                                   m.roi.width, m.roi.do_rectify))))
            elif channel.topic == "/joint_states":
                out.append(("joints", ros.JointState(header(m), list(m.name), list(m.position), list(m.velocity),
                                                     list(m.effort))))
    return out


def png(image: ros.Image) -> ros.CompressedImage:
    """An ``rgb8`` image as a ``CompressedImage`` holding a PNG file (lossless: it decodes
    to the same pixels)."""
    assert image.encoding == "rgb8"
    raw = bytes(image.data)
    rows = b"".join(b"\x00" + raw[y * image.step:y * image.step + 3 * image.width] for y in range(image.height))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    data = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", image.width, image.height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return ros.CompressedImage(image.header, "png", list(data))


def stamp_ns(h: ros.Header) -> int:
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def wait_for(predicate: Any, timeout_s: float, what: str, proc: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert proc.poll() is None, f"the bridge exited ({proc.returncode}) while waiting for {what}:\n" + log.read_text()
        assert time.monotonic() < deadline, f"timed out waiting for {what}; bridge log:\n" + log.read_text()
        time.sleep(0.05)


@pytest.mark.parametrize("compressed", [False, True], ids=["image", "compressed_png"])
def test_cyclone_dds_robot_gets_the_scores_vamos_score_gives(tmp_path: Path, compressed: bool) -> None:
    bin = vamos_bin()
    server = Server(bin, tmp_path / "server")
    try:
        # The reference: the same bag scored offline with the same profile.
        reference = {int(r["stamp_ns"]): r for r in server.offline(EPISODE)}
        assert len(reference) >= 20

        # A domain of its own, so parallel runs on one host do not meet.
        domain = random.randint(100, 200)
        log = tmp_path / "bridge.log"
        env = dict(server.env, VAMOS_ROBOT_TOKEN=ROBOT, VAMOS_LOG__LEVEL="info")
        with log.open("wb") as err:
            bridge = subprocess.Popen(
                [str(bin), "bridge", "--server", f"http://{server.grpc}", "--profile", "sim-arm",
                 "--namespace", "robot1", "--domain-id", str(domain), "--diagnostics-period", "0.2",
                 *(["--compressed"] if compressed else [])],
                stdout=subprocess.DEVNULL, stderr=err, env=env)
        try:
            dp = DomainParticipant(domain)
            topic = lambda name, ty: Topic(dp, name, ty)  # noqa: E731
            image_type = ros.CompressedImage if compressed else ros.Image
            image_w = DataWriter(dp, topic("rt/robot1/camera/image_raw", image_type), qos=RELIABLE)
            info_w = DataWriter(dp, topic("rt/robot1/camera/camera_info", ros.CameraInfo), qos=RELIABLE)
            joints_w = DataWriter(dp, topic("rt/robot1/joint_states", ros.JointState), qos=RELIABLE)
            # Another robot's camera in the same domain: the namespace keeps it out.
            other_w = DataWriter(dp, topic("rt/robot2/camera/image_raw", image_type), qos=RELIABLE)
            scores_r = DataReader(dp, topic("rt/robot1/vamos/frame_score", ros.FrameScore), qos=RELIABLE)
            plain_r = DataReader(dp, topic("rt/robot1/vamos/score", ros.Float64), qos=RELIABLE)
            anomaly_r = DataReader(dp, topic("rt/robot1/vamos/anomaly", ros.Bool), qos=RELIABLE)
            diag_r = DataReader(dp, topic("rt/diagnostics", ros.DiagnosticArray), qos=RELIABLE)

            # Discovery both ways before the first sample (best-effort readers on the
            # bridge's side would miss samples written before they matched).
            wait_for(lambda: all(w.get_matched_subscriptions() for w in (image_w, info_w, joints_w)), 30,
                     "the bridge's subscriptions", bridge, log)
            wait_for(lambda: scores_r.get_matched_publications() and diag_r.get_matched_publications(), 30,
                     "the bridge's publishers", bridge, log)

            messages = read_episode(EPISODE)
            images = [m for kind, m in messages if kind == "image"]
            scores: list[ros.FrameScore] = []
            plain: list[float] = []
            anomalies: list[bool] = []
            diagnostics: list[ros.DiagnosticArray] = []

            def take(reader: DataReader, ty: type) -> list[Any]:
                # Without the InvalidSample notices of a writer that left.
                return [m for m in reader.take(N=100) if isinstance(m, ty)]

            def drain() -> None:
                scores.extend(take(scores_r, ros.FrameScore))
                plain.extend(m.data for m in take(plain_r, ros.Float64))
                anomalies.extend(m.data for m in take(anomaly_r, ros.Bool))
                diagnostics.extend(take(diag_r, ros.DiagnosticArray))

            sent = 0
            for kind, m in messages:
                if kind == "image":
                    # Paced by the answers, as a robot within the server's queue would be.
                    wait_for(lambda: (drain(), len(scores) >= sent - 3)[1], 30, "scores", bridge, log)
                    image_w.write(png(m) if compressed else m)
                    other_w.write(png(m) if compressed else m)
                    sent += 1
                elif kind == "camera_info":
                    info_w.write(m)
                else:
                    joints_w.write(m)
            # The last images are scored once later joint states arrive or the session
            # ends: stop the bridge (SIGTERM) and collect what it publishes before it exits.
            time.sleep(0.5)
            bridge.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + 20
            while bridge.poll() is None and time.monotonic() < deadline:
                drain()
                time.sleep(0.05)
            assert bridge.wait(timeout=5) == 0, log.read_text()
            time.sleep(0.3)
            drain()
        finally:
            if bridge.poll() is None:
                bridge.kill()
                bridge.wait()

        text = log.read_text()
        assert "/robot1/camera/image_raw" in text, text
        # Every score the offline run gives, in the image's frame, equal to it.
        image_stamps = {stamp_ns(m.header) for m in images}
        got = {stamp_ns(s.header): s for s in scores}
        assert len(got) == len(scores), "one score per image"
        assert set(got) == set(reference), (sorted(set(reference) - set(got)), sorted(set(got) - set(reference)))
        assert set(got) <= image_stamps
        print(f"{len(images)} images, {len(scores)} scores, {len(diagnostics)} diagnostics")
        for ns, s in got.items():
            r = reference[ns]
            assert s.header.frame_id == images[0].header.frame_id
            assert math.isclose(s.score, r["score"], rel_tol=1e-9, abs_tol=1e-12), (ns, s.score, r["score"])
            assert s.anomaly == r["anomaly"]
            for key in ("e_c", "e_b", "e_o", "e_r", "e_k"):
                want = r.get(key)
                have = getattr(s, key)
                assert (math.isnan(have) if want is None else math.isclose(have, want, rel_tol=1e-9, abs_tol=1e-12)), \
                    (ns, key, have, want)
            assert s.session_id.startswith("robot1-") and s.latency_s >= 0
        # The plain outputs follow the stamped ones, one each per score.
        assert plain == [s.score for s in scores]
        assert anomalies == [s.anomaly for s in scores]
        # Diagnostics: the bridge's status, OK while scoring, with its counters and topics.
        statuses = [st for d in diagnostics for st in d.status]
        assert statuses and all(st.hardware_id == "robot1" for st in statuses)
        assert all(st.name == "vamos: /robot1/vamos_bridge" for st in statuses)
        ok = [st for st in statuses if st.level in (0, b"\x00") and st.message.startswith("scoring")]
        assert ok, [(st.level, st.message) for st in statuses]
        values = dict((kv.key, kv.value) for kv in statuses[-1].values)
        assert values["image_topic"] == "/robot1/camera/image_raw"
        assert values["profile"] == "sim-arm"
        assert int(values["images_sent"]) == len(images), values
        assert int(values["frames_scored"]) == len(scores)
    finally:
        server.stop()
