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

import copy
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
from _server import ROBOT, Server, free_port, vamos_bin  # noqa: E402

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


class Robot:
    """A robot on Cyclone DDS in its own domain (parallel runs on one host do not meet):
    writers of robot1's camera, camera info and joint states (and robot2's camera; with
    ``depth``, robot1's depth camera, which the bridge is told to read), readers of the
    bridge's outputs, and ``vamos bridge`` itself, started on ``server_url``."""

    def __init__(self, bin: Path, tmp: Path, server_url: str, env: dict[str, str], compressed: bool = False,
                 extra: tuple[str, ...] = (), depth: bool = False) -> None:
        self.compressed = compressed
        domain = random.randint(100, 200)
        self.log = tmp / "bridge.log"
        with self.log.open("wb") as err:
            self.bridge = subprocess.Popen(
                [str(bin), "bridge", "--server", server_url, "--profile", "sim-arm", "--namespace", "robot1",
                 "--domain-id", str(domain), "--diagnostics-period", "0.2",
                 *(["--compressed"] if compressed else []),
                 *(["--depth-topic", "camera/depth/image_raw"] if depth else []), *extra],
                stdout=subprocess.DEVNULL, stderr=err,
                env=dict(env, VAMOS_ROBOT_TOKEN=ROBOT, VAMOS_LOG__LEVEL="info"))
        dp = DomainParticipant(domain)
        topic = lambda name, ty: Topic(dp, name, ty)  # noqa: E731
        image_type = ros.CompressedImage if compressed else ros.Image
        self.image_w = DataWriter(dp, topic("rt/robot1/camera/image_raw", image_type), qos=RELIABLE)
        self.info_w = DataWriter(dp, topic("rt/robot1/camera/camera_info", ros.CameraInfo), qos=RELIABLE)
        self.joints_w = DataWriter(dp, topic("rt/robot1/joint_states", ros.JointState), qos=RELIABLE)
        self.depth_w = DataWriter(dp, topic("rt/robot1/camera/depth/image_raw", ros.Image), qos=RELIABLE) \
            if depth else None
        # Another robot's camera in the same domain: the namespace keeps it out.
        self.other_w = DataWriter(dp, topic("rt/robot2/camera/image_raw", image_type), qos=RELIABLE)
        self.scores_r = DataReader(dp, topic("rt/robot1/vamos/frame_score", ros.FrameScore), qos=RELIABLE)
        self.plain_r = DataReader(dp, topic("rt/robot1/vamos/score", ros.Float64), qos=RELIABLE)
        self.anomaly_r = DataReader(dp, topic("rt/robot1/vamos/anomaly", ros.Bool), qos=RELIABLE)
        self.diag_r = DataReader(dp, topic("rt/diagnostics", ros.DiagnosticArray), qos=RELIABLE)
        self.scores: list[ros.FrameScore] = []
        self.plain: list[float] = []
        self.anomalies: list[bool] = []
        self.statuses: list[ros.DiagnosticStatus] = []
        self.offset_ns = 0
        # Discovery both ways before the first sample (the bridge's best-effort readers
        # would miss samples written before they matched).
        writers = [self.image_w, self.info_w, self.joints_w, *([self.depth_w] if self.depth_w else [])]
        self.wait_for(lambda: all(w.get_matched_subscriptions() for w in writers), 30, "the bridge's subscriptions")
        self.wait_for(lambda: self.scores_r.get_matched_publications() and self.diag_r.get_matched_publications(),
                      30, "the bridge's publishers")

    def wait_for(self, predicate: Any, timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            assert self.bridge.poll() is None, \
                f"the bridge exited ({self.bridge.returncode}) while waiting for {what}:\n" + self.log.read_text()
            assert time.monotonic() < deadline, f"timed out waiting for {what}; bridge log:\n" + self.log.read_text()
            time.sleep(0.05)
            self.drain()

    def drain(self) -> None:
        def take(reader: DataReader, ty: type) -> list[Any]:
            # Without the InvalidSample notices of a writer that left.
            return [m for m in reader.take(N=100) if isinstance(m, ty)]

        self.scores.extend(take(self.scores_r, ros.FrameScore))
        self.plain.extend(m.data for m in take(self.plain_r, ros.Float64))
        self.anomalies.extend(m.data for m in take(self.anomaly_r, ros.Bool))
        self.statuses.extend(st for d in take(self.diag_r, ros.DiagnosticArray) for st in d.status)

    def write(self, kind: str, m: Any, other_robot: bool = False) -> None:
        """Publishes one message of the bag, its stamp moved on by the passes before
        (a session's stamps only go forward)."""
        if self.offset_ns:
            m = copy.copy(m)
            ns = stamp_ns(m.header) + self.offset_ns
            m.header = ros.Header(ros.Time(ns // 1_000_000_000, ns % 1_000_000_000), m.header.frame_id)
        if kind == "image":
            image = png(m) if self.compressed else m
            self.image_w.write(image)
            if other_robot:
                self.other_w.write(image)
        elif kind == "camera_info":
            self.info_w.write(m)
        elif kind == "depth":
            assert self.depth_w is not None
            self.depth_w.write(m)
        else:
            self.joints_w.write(m)

    def next_pass(self, messages: list[tuple[str, Any]]) -> None:
        stamps = [stamp_ns(m.header) for _, m in messages]
        self.offset_ns += max(stamps) - min(stamps) + 1_000_000_000

    def play(self, messages: list[tuple[str, Any]], ahead: int = 3) -> None:
        """Publishes the messages in order, each image once the bridge has published
        scores for all but ``ahead`` of the images before it (a robot within the
        server's queue)."""
        base = len(self.scores)
        sent = 0
        for kind, m in messages:
            if kind == "image":
                self.wait_for(lambda: len(self.scores) - base >= sent - ahead, 30, "scores")
                sent += 1
            self.write(kind, m, other_robot=True)
        self.next_pass(messages)

    def stream_until(self, messages: list[tuple[str, Any]], done: Any, what: str, timeout_s: float = 20) -> None:
        """Publishes the messages round and round at about 25 messages a second, not paced
        by scores, until ``done()``."""
        deadline = time.monotonic() + timeout_s
        while True:
            for kind, m in messages:
                self.write(kind, m)
                time.sleep(0.04)
                self.drain()
                if done():
                    self.next_pass(messages)
                    return
                assert self.bridge.poll() is None, self.log.read_text()
                assert time.monotonic() < deadline, f"timed out waiting for {what}; bridge log:\n" + self.log.read_text()
            self.next_pass(messages)

    def stop(self) -> str:
        """SIGTERM, collecting what the bridge publishes until it exits; its log."""
        # The last images are scored once later joint states arrive or the session ends.
        time.sleep(0.5)
        self.bridge.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 20
        while self.bridge.poll() is None and time.monotonic() < deadline:
            self.drain()
            time.sleep(0.05)
        assert self.bridge.wait(timeout=5) == 0, self.log.read_text()
        time.sleep(0.3)
        self.drain()
        return self.log.read_text()

    def kill(self) -> None:
        if self.bridge.poll() is None:
            self.bridge.kill()
            self.bridge.wait()


@pytest.mark.parametrize("compressed", [False, True], ids=["image", "compressed_png"])
def test_cyclone_dds_robot_gets_the_scores_vamos_score_gives(tmp_path: Path, compressed: bool) -> None:
    bin = vamos_bin()
    server = Server(bin, tmp_path / "server")
    try:
        # The reference: the same bag scored offline with the same profile.
        reference = {int(r["stamp_ns"]): r for r in server.offline(EPISODE)}
        assert len(reference) >= 20
        robot = Robot(bin, tmp_path, f"http://{server.grpc}", server.env, compressed)
        try:
            messages = read_episode(EPISODE)
            images = [m for kind, m in messages if kind == "image"]
            robot.play(messages)
            text = robot.stop()
        finally:
            robot.kill()
    finally:
        server.stop()

    assert "/robot1/camera/image_raw" in text, text
    scores = robot.scores
    # Every score the offline run gives, in the image's frame, equal to it.
    got = {stamp_ns(s.header): s for s in scores}
    assert len(got) == len(scores), "one score per image"
    # On failure: the bridge's own counts and warnings say on which side a score went missing.
    last = dict((kv.key, kv.value) for kv in robot.statuses[-1].values) if robot.statuses else {}
    why = (f"bridge: {last}; {len(robot.plain)} plain scores; warnings: "
           + "".join(line for line in text.splitlines(keepends=True) if "WARN" in line and "vamos" in line))
    assert set(got) == set(reference), (sorted(set(reference) - set(got)), sorted(set(got) - set(reference)), why)
    assert set(got) <= {stamp_ns(m.header) for m in images}
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
    assert robot.plain == [s.score for s in scores]
    assert robot.anomalies == [s.anomaly for s in scores]
    # Diagnostics: the bridge's status, OK while scoring, with its counters and topics.
    statuses = robot.statuses
    assert statuses and all(st.hardware_id == "robot1" for st in statuses)
    assert all(st.name == "vamos: /robot1/vamos_bridge" for st in statuses)
    assert any(st.level == 0 and st.message.startswith("scoring") for st in statuses), \
        [(st.level, st.message) for st in statuses]
    values = dict((kv.key, kv.value) for kv in statuses[-1].values)
    assert values["image_topic"] == "/robot1/camera/image_raw"
    assert values["profile"] == "sim-arm"
    # robot2's images never reached the session.
    assert int(values["images_sent"]) == len(images), values
    assert int(values["frames_scored"]) == len(scores)


def test_bridge_waits_for_a_late_server_and_reconnects_after_a_restart(tmp_path: Path) -> None:
    """Robots boot before servers, and servers restart: the bridge reports ERROR while it
    cannot reach vamos, opens the session when the server comes up, and opens it again
    after the server restarted, with no restart of its own."""
    bin = vamos_bin()
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    messages = read_episode(EPISODE)
    robot = Robot(bin, tmp_path, f"http://127.0.0.1:{port}", env, extra=("--session-id", "robot1-late"))
    try:
        # No server: images are dropped, the diagnostics say why.
        robot.stream_until(messages, lambda: any(st.level == 2 and st.message.startswith("not connected to vamos")
                                                 for st in robot.statuses), "an ERROR diagnostic")
        assert not robot.scores
        for round_ in range(2):
            server = Server(bin, tmp_path / f"server{round_}", grpc_port=port)
            try:
                before = len(robot.scores)
                # A robot streams on: the bridge opens the session at an image after the
                # server is up (it tries at most once a second).
                robot.stream_until(messages, lambda: len(robot.scores) > before, "the first score")
                robot.play(messages)
                robot.wait_for(lambda: len(robot.scores) - before >= 20, 30, "scores after the server came up")
            finally:
                server.stop()
            robot.statuses.clear()
            robot.wait_for(lambda: any(st.level == 2 for st in robot.statuses), 10, "ERROR after the server stopped")
        text = robot.stop()
    finally:
        robot.kill()
    assert all(s.session_id == "robot1-late" for s in robot.scores)
    values = dict((kv.key, kv.value) for kv in robot.statuses[-1].values)
    assert int(values["reconnects"]) >= 1, values
    assert "cannot open the session" in text, text


def with_depth(messages: list[tuple[str, Any]]) -> tuple[list[tuple[str, Any]], int, int]:
    """The messages with a 16UC1 depth image (1.5 m) written before each camera image, by
    turns: 4 ms after the image's stamp at 80x60 (the camera's 4:3), 3 ms before it at
    50x50 (another aspect ratio: the server refuses it), and 45 ms after it at 50x50
    (images are 100 ms apart: within 20 ms of none, so never sent). Also the number
    paired, and of those the number the server refuses."""
    out: list[tuple[str, Any]] = []
    paired = refused = images = 0
    for kind, m in messages:
        if kind == "image":
            ns = stamp_ns(m.header)
            offset_ms, w, h = [(4, 80, 60), (-3, 50, 50), (45, 50, 50)][images % 3]
            at = ns + offset_ms * 1_000_000
            out.append(("depth", ros.Image(ros.Header(ros.Time(at // 1_000_000_000, at % 1_000_000_000), "depth"),
                                           h, w, "16UC1", 0, 2 * w, list(struct.pack("<H", 1500) * (w * h)))))
            paired += images % 3 != 2
            refused += images % 3 == 1
            images += 1
        out.append((kind, m))
    return out, paired, refused


def test_depth_images_reach_vamos_with_their_images(tmp_path: Path) -> None:
    """``--depth-topic``: each camera image goes with the depth image nearest its stamp
    within 20 ms. Seen at the server: each paired depth image of another aspect ratio is
    refused there with a message (one per such image, none for the depth image too far
    from any image, none for the good ones), and every image is scored all the same."""
    bin = vamos_bin()
    server = Server(bin, tmp_path / "server")
    try:
        reference = {int(r["stamp_ns"]) for r in server.offline(EPISODE)}
        robot = Robot(bin, tmp_path, f"http://{server.grpc}", server.env, depth=True)
        try:
            messages, paired, refused = with_depth(read_episode(EPISODE))
            robot.play(messages)
            text = robot.stop()
        finally:
            robot.kill()
    finally:
        server.stop()

    assert "with depth from /robot1/camera/depth/image_raw (within 20 ms)" in text, text
    images = [m for kind, m in messages if kind == "image"]
    got = [stamp_ns(s.header) for s in robot.scores]
    assert len(got) == len(set(got)) == len(images) and set(got) == reference, text
    values = dict((kv.key, kv.value) for kv in robot.statuses[-1].values)
    assert values["depth_topic"] == "/robot1/camera/depth/image_raw"
    assert int(values["images_sent"]) == len(images), values
    assert int(values["images_with_depth"]) == paired, (values, paired)
    assert int(values["refused"]) == refused >= 5, (values, refused, text)
    refusals = [line for line in text.splitlines() if "vamos refused a message: depth image refused" in line]
    assert len(refusals) == refused and all("50x50" in line and "aspect ratio" in line for line in refusals), text
