"""Bags written by vamos (``vamos episode copy``, i.e. ``ScoreBagWriter``) read back with
the official MCAP readers (``mcap``, ``mcap-ros2-support``): schemas, CDR and values.

Needs the ``vamos`` binary: ``VAMOS_BIN`` names it. Without ``VAMOS_BIN`` (or without the
``mcap`` packages) the test is skipped; with a ``VAMOS_BIN`` that does not exist it fails.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

FIXTURES = Path(__file__).resolve().parents[3] / "tests" / "fixtures" / "episode"


@pytest.fixture(scope="module")
def vamos_bin() -> Path:
    value = os.environ.get("VAMOS_BIN")
    if not value:
        pytest.skip("VAMOS_BIN is not set (scripts/test.sh sets it)")
    path = Path(value)
    assert path.is_file(), f"VAMOS_BIN={value} does not exist"
    return path


def _messages(path: Path):
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        summary = reader.get_summary()
        out = list(reader.iter_decoded_messages(log_time_order=True))
    return summary, out


def test_copied_bag_decodes_with_the_official_reader(vamos_bin: Path, tmp_path: Path) -> None:
    src = FIXTURES / "rgb8_zstd.mcap"
    dst = tmp_path / "copy.mcap"
    run = subprocess.run([str(vamos_bin), "episode", "copy", str(src), str(dst)],
                         capture_output=True, text=True,
                         env={k: v for k, v in os.environ.items() if k != "VAMOS_CONFIG"})
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["frames"] == 20

    expected = json.loads((FIXTURES / "expected.json").read_text())
    bag = next(b for b in expected["bags"] if b["file"] == "rgb8_zstd.mcap")
    summary, msgs = _messages(dst)
    assert summary is not None and summary.statistics.message_count > 0
    chunks = {c.compression for c in summary.chunk_indexes}
    assert chunks == {"zstd"}
    by_topic: dict[str, list] = {}
    for schema, channel, message, decoded in msgs:
        assert channel.message_encoding == "cdr"
        assert schema.encoding == "ros2msg"
        by_topic.setdefault(channel.topic, []).append((schema.name, message, decoded))

    # Images copied unchanged: same CDR bytes as the input, log time = header stamp.
    _, src_msgs = _messages(src)
    src_images = [m for s, c, m, d in src_msgs if c.topic == "/camera/image_raw"]
    images = by_topic["/camera/image_raw"]
    assert [m.data for _, m, _ in images] == [m.data for m in src_images]
    for (_, message, img), want in zip(images, bag["frames"]):
        stamp = img.header.stamp.sec * 10**9 + img.header.stamp.nanosec
        assert stamp == want["stamp_ns"] == message.log_time

    # The decoded gray image as mono8 (sensor_msgs/msg/Image written by vamos).
    grays = by_topic["/vamos/gray"]
    assert grays[0][0] == "sensor_msgs/msg/Image"
    for (_, _, g), want in zip(grays, bag["frames"]):
        assert (g.width, g.height, g.encoding, g.step) == (64, 48, "mono8", 64)
        arr = np.frombuffer(bytes(g.data), np.uint8).reshape(48, 64)
        for x, y, v in want["pixels"]:
            assert abs(int(arr[y, x]) - v) <= 0.5 + 1e-3

    # Float64 and Bool diagnostics per frame: the joint gap and extrapolation flag.
    gaps = by_topic["/vamos/joint_gap_ms"]
    flags = by_topic["/vamos/joints_extrapolated"]
    assert gaps[0][0] == "std_msgs/msg/Float64" and flags[0][0] == "std_msgs/msg/Bool"
    for (_, _, gap), (_, _, flag), want in zip(gaps, flags, bag["frames"]):
        assert gap.data == pytest.approx(want["joints"]["gap_ns"] * 1e-6, abs=1e-9)
        assert flag.data == want["joints"]["extrapolated"]

    # Other topics copied with their schemas; they decode to the input's values.
    joints = by_topic["/joint_states"]
    assert joints[0][0] == "sensor_msgs/msg/JointState" and len(joints) == bag["joint_messages"]
    assert list(joints[0][2].name) == expected["joints"]
    info = by_topic["/camera/camera_info"][0][2]
    assert list(info.k) == bag["k"]
    assert by_topic["/robot_description"][0][2].data == expected["urdf"]


def test_scored_bag_decodes_with_the_official_reader(vamos_bin: Path, tmp_path: Path) -> None:
    """``vamos score --mcap`` with a model: the official reader decodes /vamos/score and
    /vamos/e_o as Float64 (the values of the JSON lines), /vamos/anomaly as Bool and
    /vamos/heatmap as a 64x64 rgb8 Image, one per frame with e_o."""
    model = FIXTURES.parent / "model" / "valid.vamos"
    profile = tmp_path / "p.toml"
    profile.write_text(
        f'name = "p"\nmodel = "{model}"\nflow_preset = "realtime"\n'
        "[pipeline]\nstride = 1\n[pipeline.frames]\nwidth = 64\nheight = 48\n"
        'variant = "plain"\n'
    )
    out = tmp_path / "out"
    run = subprocess.run([str(vamos_bin), "score", "--profile", str(profile),
                          str(FIXTURES / "rgb8_zstd.mcap"), "-o", str(out), "--mcap",
                          "--no-progress"],
                         capture_output=True, text=True,
                         env={k: v for k, v in os.environ.items() if k != "VAMOS_CONFIG"})
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in
             (out / "rgb8_zstd.scores.jsonl").read_text().splitlines()]
    assert len(lines) == 20
    e_o = [f["e_o"] for f in lines if f["e_o"] is not None]
    assert len(e_o) == 15  # processed frame 0 has no flow, then A + B = 4 of history

    _, msgs = _messages(out / "rgb8_zstd.scored.mcap")
    by_topic: dict[str, list] = {}
    for schema, channel, _, decoded in msgs:
        by_topic.setdefault(channel.topic, []).append((schema.name, decoded))
    assert {s for s, _ in by_topic["/vamos/score"]} == {"std_msgs/msg/Float64"}
    assert [d.data for _, d in by_topic["/vamos/score"]] == [f["score"] for f in lines]
    assert [d.data for _, d in by_topic["/vamos/anomaly"]] == [f["anomaly"] for f in lines]
    assert [d.data for _, d in by_topic["/vamos/e_o"]] == e_o
    assert "/vamos/e_c" not in by_topic and "/vamos/e_b" not in by_topic  # no robot
    maps = by_topic["/vamos/heatmap"]
    assert len(maps) == len(e_o)
    for schema, img in maps:
        assert schema == "sensor_msgs/msg/Image"
        assert (img.width, img.height, img.encoding, img.step) == (64, 64, "rgb8", 64 * 3)
        assert len(bytes(img.data)) == 64 * 64 * 3
