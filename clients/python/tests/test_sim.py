"""vamos-sim: smoke generation, bag contents, labels, determinism, the URDF."""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import zlib
from pathlib import Path

import pytest

np = pytest.importorskip("numpy")
pytest.importorskip("pybullet")
pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")
pytest.importorskip("tqdm")

from mcap_ros2.reader import read_ros2_messages  # noqa: E402

from vamos.sim import robot as rb  # noqa: E402
from vamos.sim.cli import main, plan_episodes  # noqa: E402
from vamos.sim.episode import (  # noqa: E402
    ANOMALY_TYPES,
    BOOK_THICKNESS_M,
    EPOCH_NS,
    EpisodeSpec,
    _last_away_from_rest,
    generate_episode,
)

pytestmark = pytest.mark.sim

TOPICS = {"/camera/image_raw", "/camera/camera_info", "/joint_states", "/robot_description"}


def _read(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    for m in read_ros2_messages(str(path)):
        out.setdefault(m.channel.topic, []).append(m)
    return out


def _stamp_ns(msg) -> int:
    return msg.ros_msg.header.stamp.sec * 1_000_000_000 + msg.ros_msg.header.stamp.nanosec


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("smoke")
    assert main(["generate", "--out", str(out), "--smoke", "--seed", "5", "--workers", "2", "--no-progress"]) == 0
    return out


def test_urdf_asset_is_the_generator_output_and_loads_in_pybullet() -> None:
    import pybullet as pb

    assert rb.asset_path().read_text() == rb.urdf_text()
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(rb.asset_path()), useFixedBase=True, physicsClientId=client)
        count = pb.getNumJoints(body, physicsClientId=client)
        infos = [pb.getJointInfo(body, i, physicsClientId=client) for i in range(count)]
        movable = [i[1].decode() for i in infos if i[2] != pb.JOINT_FIXED]
        assert movable == list(rb.MOVABLE_JOINTS)
        links = [i[12].decode() for i in infos]
        assert rb.CAMERA_FRAME in links and rb.TOOL_LINK in links
        # The optical frame looks along the camera link's x axis (z forward, y down).
        cam = links.index(rb.CAMERA_FRAME)
        _, orn = pb.getLinkState(body, cam, computeForwardKinematics=True, physicsClientId=client)[4:6]
        m = pb.getMatrixFromQuaternion(orn)
        z_axis = (m[2], m[5], m[8])
        y_axis = (m[1], m[4], m[7])
        # Head at zero: camera looks along +x, image y points down (-z).
        assert z_axis == pytest.approx((1.0, 0.0, 0.0), abs=1e-6)
        assert y_axis == pytest.approx((0.0, 0.0, -1.0), abs=1e-6)
    finally:
        pb.disconnect(client)


def test_fixed_camera_looks_at_its_target_whatever_the_joints(tmp_path: Path) -> None:
    import pybullet as pb

    urdf = tmp_path / "fixed.urdf"
    urdf.write_text(rb.urdf_text("fixed"))
    assert rb.urdf_text("fixed").startswith(rb.urdf_text().removesuffix("</robot>\n"))
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(urdf), useFixedBase=True, physicsClientId=client)
        infos = [pb.getJointInfo(body, i, physicsClientId=client) for i in range(pb.getNumJoints(body, client))]
        movable = [i[1].decode() for i in infos if i[2] != pb.JOINT_FIXED]
        assert movable == list(rb.MOVABLE_JOINTS)
        cam = [i[12].decode() for i in infos].index(rb.FIXED_CAMERA_FRAME)
        poses = []
        for q in (0.0, 0.7):
            for i in infos:
                if i[2] != pb.JOINT_FIXED:
                    pb.resetJointState(body, i[0], q, physicsClientId=client)
            pos, orn = pb.getLinkState(body, cam, computeForwardKinematics=True, physicsClientId=client)[4:6]
            poses.append((pos, orn))
        assert poses[0][0] == pytest.approx(poses[1][0], abs=1e-9)
        assert poses[0][1] == pytest.approx(poses[1][1], abs=1e-9)
        pos, orn = poses[0]
        assert pos == pytest.approx(rb.FIXED_CAMERA_XYZ, abs=1e-6)
        m = pb.getMatrixFromQuaternion(orn)
        z_axis = np.array((m[2], m[5], m[8]))
        look = np.array(rb.FIXED_CAMERA_TARGET) - np.array(pos)
        assert z_axis == pytest.approx(look / np.linalg.norm(look), abs=1e-6)
        # Image rows run down: the optical y axis points below the horizon.
        assert m[7] < 0.0
    finally:
        pb.disconnect(client)


def test_fixed_camera_episode(tmp_path: Path) -> None:
    assert main(["generate", "--out", str(tmp_path), "--smoke", "--seed", "5", "--train", "1", "--test-nominal",
                 "0", "--test-anomalous", "0", "--camera", "fixed", "--workers", "1", "--no-progress"]) == 0
    ds = json.loads((tmp_path / "dataset.json").read_text())
    assert ds["camera_mount"] == "fixed"
    assert (tmp_path / "robot" / "vamos_arm.urdf").read_text() == rb.urdf_text("fixed")
    assert json.loads((tmp_path / "camera.json").read_text())["frame"] == rb.FIXED_CAMERA_FRAME
    msgs = _read(tmp_path / "train" / "train_0000.mcap")
    assert msgs["/robot_description"][0].ros_msg.data == rb.urdf_text("fixed")
    images = msgs["/camera/image_raw"]
    assert {m.ros_msg.header.frame_id for m in images} == {rb.FIXED_CAMERA_FRAME}
    assert {m.ros_msg.header.frame_id for m in msgs["/camera/camera_info"]} == {rb.FIXED_CAMERA_FRAME}
    # The camera stands still while the arm works: the image's top rows (wall) stay the
    # same from the first frame to the middle one, while the arm changes the image.
    first, middle = (np.frombuffer(m.ros_msg.data, np.uint8).reshape(120, 160, 3).astype(int)
                     for m in (images[0], images[len(images) // 2]))
    assert np.abs(first[:8] - middle[:8]).mean() < 1.0
    assert np.abs(first - middle).mean() > 1.5


def test_wrist_camera_episode_with_depth(tmp_path: Path) -> None:
    from vamos.sim.bag import DEPTH_TOPIC
    from vamos.sim.episode import FAR_M, NEAR_M

    assert main(["generate", "--out", str(tmp_path), "--smoke", "--seed", "5", "--train", "1", "--test-nominal",
                 "0", "--test-anomalous", "0", "--camera", "wrist", "--depth", "--workers", "1",
                 "--no-progress"]) == 0
    ds = json.loads((tmp_path / "dataset.json").read_text())
    assert (ds["camera_mount"], ds["depth_topic"]) == ("wrist", DEPTH_TOPIC)
    assert json.loads((tmp_path / "camera.json").read_text())["frame"] == rb.WRIST_CAMERA_FRAME
    urdf = (tmp_path / "robot" / "vamos_arm.urdf").read_text()
    assert urdf == rb.urdf_text("wrist") and f'<child link="{rb.WRIST_CAMERA_FRAME}"/>' in urdf
    msgs = _read(tmp_path / "train" / "train_0000.mcap")
    images, depths = msgs["/camera/image_raw"], msgs[DEPTH_TOPIC]
    # One depth image per image, same stamp and frame, 16UC1 millimetres.
    assert [_stamp_ns(m) for m in depths] == [_stamp_ns(m) for m in images]
    d = depths[0].ros_msg
    assert (d.encoding, d.width, d.height, d.step, d.header.frame_id) == ("16UC1", 160, 120, 320,
                                                                         rb.WRIST_CAMERA_FRAME)
    mm = np.frombuffer(d.data, "<u2").reshape(120, 160).astype(float)
    seen = mm[mm > 0] / 1000.0
    assert seen.size > 0.9 * mm.size and seen.min() >= NEAR_M and seen.max() <= FAR_M
    # The fingertips sit in the top corners, about a finger's length away; the scene below
    # the gripper is farther.
    for corner in (mm[:10, :20], mm[:10, -20:]):
        assert 0.05 < corner[corner > 0].min() / 1000.0 < 0.2
    assert np.median(mm[60:, 40:120]) / 1000.0 > 0.25
    # The camera moves with the tool: the image changes from the first frame to the middle.
    first, middle = (np.frombuffer(m.ros_msg.data, np.uint8).reshape(120, 160, 3).astype(int)
                     for m in (images[0], images[len(images) // 2]))
    assert np.abs(first - middle).mean() > 5.0
    # The client's reader takes the colour topic as the image, and the depth when asked.
    from vamos.client import read_episode

    bag = tmp_path / "train" / "train_0000.mcap"
    plain = [m.image for _, m in read_episode(bag).messages if m.WhichOneof("message") == "image"]
    assert len(plain) == len(images) and not any(i.HasField("depth") for i in plain)
    with_depth = [m.image for _, m in read_episode(bag, depth_topic=DEPTH_TOPIC).messages
                  if m.WhichOneof("message") == "image"]
    assert [(i.encoding, i.depth.encoding, i.depth.data) for i in with_depth] == [
        ("rgb8", "16UC1", bytes(m.ros_msg.data)) for m in depths]


def test_smoke_dataset_layout(smoke: Path) -> None:
    ds = json.loads((smoke / "dataset.json").read_text())
    assert ds["seed"] == 5 and ds["counts"] == {"train": 2, "val": 0, "test": 3}
    assert (smoke / "robot" / "vamos_arm.urdf").read_text() == rb.urdf_text()
    cam = json.loads((smoke / "camera.json").read_text())
    f = 60.0 / math.tan(math.radians(25.0))  # 120 px high, 50 degrees vertical field of view
    assert cam == {"frame": rb.CAMERA_FRAME, "convention": "optical", "width": 160, "height": 120,
                   "fx": pytest.approx(f), "fy": pytest.approx(f), "cx": 79.5, "cy": 59.5}
    assert [e["anomaly_type"] for e in ds["episodes"]] == [None, None, None, "book_falls", "book_slips"]
    for e in ds["episodes"]:
        assert (smoke / e["path"]).is_file()
        assert 2.0 < e["duration_s"] < 6.0
        # The task: nominal episodes leave the book standing in its slot and the shelf's books
        # standing; a book that falls off the shelf or slips from the gripper does not end there
        # (and may knock the shelf's books).
        assert e["task"]["placed"] is (e["anomaly_type"] is None), e
        if e["anomaly_type"] is None:
            assert e["task"]["shelf_books_fallen"] == 0


def test_bags_topics_rates_stamps(smoke: Path) -> None:
    cam = json.loads((smoke / "camera.json").read_text())
    for bag in sorted(smoke.glob("*/*.mcap")):
        msgs = _read(bag)
        assert set(msgs) == TOPICS, bag
        assert len(msgs["/robot_description"]) == 1
        assert msgs["/robot_description"][0].ros_msg.data == rb.urdf_text()
        images = msgs["/camera/image_raw"]
        stamps = [_stamp_ns(m) for m in images]
        assert stamps[0] == EPOCH_NS
        assert all(b - a == 100_000_000 for a, b in zip(stamps[:-1], stamps[1:], strict=True))  # 10 Hz exactly
        js = [_stamp_ns(m) for m in msgs["/joint_states"]]
        assert all(b - a == 20_000_000 for a, b in zip(js[:-1], js[1:], strict=True))  # 50 Hz
        assert js[0] == EPOCH_NS and js[-1] >= stamps[-1]
        assert [m.log_time_ns for m in images] == stamps
        for m in images[:3]:
            r = m.ros_msg
            assert (r.width, r.height, r.encoding, r.step) == (160, 120, "rgb8", 480)
            assert len(r.data) == 160 * 120 * 3
            assert r.header.frame_id == rb.CAMERA_FRAME
        infos = msgs["/camera/camera_info"]
        assert [_stamp_ns(m) for m in infos] == stamps
        k = list(infos[0].ros_msg.k)
        assert k == pytest.approx([cam["fx"], 0, cam["cx"], 0, cam["fy"], cam["cy"], 0, 0, 1])
        assert infos[0].ros_msg.distortion_model == "plumb_bob" and list(infos[0].ros_msg.d) == [0.0] * 5
        j = msgs["/joint_states"][len(js) // 2].ros_msg
        assert list(j.name) == list(rb.MOVABLE_JOINTS)
        assert len(j.position) == len(j.velocity) == len(j.effort) == len(rb.MOVABLE_JOINTS)


def test_head_moves_during_the_task(smoke: Path) -> None:
    msgs = _read(smoke / "train" / "train_0000.mcap")["/joint_states"]
    pans = [m.ros_msg.position[rb.MOVABLE_JOINTS.index("head_pan_joint")] for m in msgs]
    tilts = [m.ros_msg.position[rb.MOVABLE_JOINTS.index("head_tilt_joint")] for m in msgs]
    assert max(pans) - min(pans) > 0.03
    assert max(tilts) - min(tilts) > 0.01
    # Fingers open, close on the book, open again.
    left = [m.ros_msg.position[rb.MOVABLE_JOINTS.index("finger_left_joint")] for m in msgs]
    assert left[0] > 0.045 and min(left) < 0.03 and left[-1] > 0.045


def test_the_fingers_stop_on_the_book_and_close_on_nothing_when_it_slips(smoke: Path) -> None:
    """The joint states show a grasp as a real gripper's do: the fingers stop at the book's
    faces and press with their force limit; when the book slips, they close on nothing."""
    finger = rb.MOVABLE_JOINTS.index("finger_left_joint")
    half_thinnest = BOOK_THICKNESS_M[0] / 2  # per finger, on the thinnest book

    def fingers(path: Path) -> list[tuple[int, float, float]]:
        return [(_stamp_ns(m), m.ros_msg.position[finger], abs(m.ros_msg.effort[finger]))
                for m in _read(path)["/joint_states"]]

    nominal = fingers(smoke / "train" / "train_0000.mcap")
    holding = [(q, e) for _, q, e in nominal if q < 0.75 * rb.FINGER_OPEN_M]
    assert len(holding) > 50
    assert min(q for q, _ in holding) > half_thinnest - 0.001  # never closes past the book
    assert sum(e > 0.95 * rb.FINGER_FORCE_N for _, e in holding) > 0.8 * len(holding)  # and grips it

    slip = smoke / "test" / "test_0002_book_slips"
    [[onset, _]] = json.loads(slip.with_suffix(".labels.json").read_text())["intervals_ns"]
    readings = fingers(slip.with_suffix(".mcap"))
    before = [(q, e) for t, q, e in readings if onset - 300_000_000 <= t < onset]
    after = [(q, e) for t, q, e in readings if onset + 400_000_000 <= t <= onset + 600_000_000]
    assert before and after
    assert all(q > half_thinnest - 0.001 and e > 0.95 * rb.FINGER_FORCE_N for q, e in before)
    assert all(q < 0.005 and e < 0.2 * rb.FINGER_FORCE_N for q, e in after), after


def test_labels_match_the_episodes(smoke: Path) -> None:
    for labels_path in sorted(smoke.glob("*/*.labels.json")):
        labels = json.loads(labels_path.read_text())
        name = labels_path.name.removesuffix(".labels.json")
        assert labels["episode"] == name
        stamps = [_stamp_ns(m) for m in _read(labels_path.with_name(f"{name}.mcap"))["/camera/image_raw"]]
        if labels["anomaly_type"] is None:
            assert labels == {"episode": name, "anomalous": False, "anomaly_type": None, "intervals_ns": []}
            continue
        assert labels["anomalous"] is True and name.endswith(labels["anomaly_type"])
        [[start, end]] = labels["intervals_ns"]
        assert stamps[0] <= start <= end <= stamps[-1]
        assert any(start <= s <= end for s in stamps)


def test_same_seed_same_episode(smoke: Path, tmp_path: Path) -> None:
    spec = next(s for s in plan_episodes(5, 2, 0, 1, 2, list(ANOMALY_TYPES), 160, 120, 10, True)
                if s.anomaly == "book_falls")
    generate_episode(spec, tmp_path)
    a = smoke / "test" / f"{spec.name}.labels.json"
    b = tmp_path / f"{spec.name}.labels.json"
    assert a.read_bytes() == b.read_bytes()
    # The whole bag is byte-identical (same messages, same chunking and compression).
    assert (smoke / "test" / f"{spec.name}.mcap").read_bytes() == (tmp_path / f"{spec.name}.mcap").read_bytes()
    ia = [bytes(m.ros_msg.data) for m in _read(smoke / "test" / f"{spec.name}.mcap")["/camera/image_raw"]]
    ib = [bytes(m.ros_msg.data) for m in _read(tmp_path / f"{spec.name}.mcap")["/camera/image_raw"]]
    assert ia == ib
    # Another seed gives another episode.
    other = EpisodeSpec(spec.name, spec.split, spec.index, spec.anomaly, 6, 160, 120, 10, True)
    generate_episode(other, tmp_path / "other")
    ic = [bytes(m.ros_msg.data) for m in _read(tmp_path / "other" / f"{spec.name}.mcap")["/camera/image_raw"]]
    assert ic[0] != ia[0]


def test_a_label_ends_where_the_objects_come_to_rest_not_where_they_stop_jittering() -> None:
    level = (0.0, 0.0, 0.0, 1.0)
    tilted = (0.0, math.sin(math.radians(3.0)), 0.0, math.cos(math.radians(3.0)))  # 6 degrees
    toppling = [(0.1 * i, [((0.0, 0.0, 0.3 - 0.1 * i), level)]) for i in range(4)]
    # At rest from 0.3 s on, jittering by millimetres and a degree (fast, but going nowhere).
    jitter = [(0.3 + 0.1 * i, [((0.004 * (-1) ** i, 0.0, 0.0), (0.0, 0.009 * (-1) ** i, 0.0, 1.0))])
              for i in range(1, 30)]
    assert _last_away_from_rest(toppling + jitter) == pytest.approx(0.2)
    # A slow slide of 1.2 cm (its first 2 mm are more than 1 cm from where it ends) and a
    # tilt of 6 degrees are motions.
    slide = [(0.1 * i, [((0.001 * i, 0.0, 0.0), level)]) for i in range(13)]
    assert _last_away_from_rest(slide) == pytest.approx(0.1)
    assert _last_away_from_rest([(0.0, [((0, 0, 0), level)]), (0.5, [((0, 0, 0), tilted)])]) == 0.0
    # Two bodies: the later one counts; none watched or none moved: no end.
    two = [(0.0, [((0, 0, 0), level), ((0, 0, 0), level)]), (0.4, [((0, 0, 0), level), ((0.02, 0, 0), level)]),
           (0.8, [((0, 0, 0), level), ((0.02, 0, 0), level)])]
    assert _last_away_from_rest(two) == 0.0
    assert _last_away_from_rest([]) is None
    assert _last_away_from_rest([(0.0, [((0, 0, 0), level)]), (1.0, [((0.005, 0, 0), level)])]) is None


@pytest.mark.parametrize("kind", [t for t in ANOMALY_TYPES if t not in ("book_falls", "book_slips")])
def test_each_anomaly_type_is_labelled_inside_its_episode(kind: str, tmp_path: Path) -> None:
    spec = EpisodeSpec(f"x_{kind}", "test", 3, kind, 11, 64, 48, 10, True)
    result = generate_episode(spec, tmp_path)
    labels = json.loads((tmp_path / f"x_{kind}.labels.json").read_text())
    msgs = _read(tmp_path / f"x_{kind}.mcap")
    stamps = [_stamp_ns(m) for m in msgs["/camera/image_raw"]]
    [[start, end]] = labels["intervals_ns"]
    assert labels["anomaly_type"] == kind and result.intervals_ns == [[start, end]]
    assert stamps[0] <= start < end <= stamps[-1]
    if kind == "books_knocked_over":
        assert result.task["shelf_books_fallen"] >= 1, result.task
        # The anomalous motion is the whole detour: the arm leaves from above the slot, goes
        # far from there and is back (the same joint positions) when it ends, inside the label.
        back = EPOCH_NS + round(result.details["motion_end"] * 1e9)
        assert back <= end
        arm = [m.ros_msg.position[:6] for m in msgs["/joint_states"] if start <= _stamp_ns(m) <= back]
        gap = [max(abs(x - y) for x, y in zip(arm[0], q, strict=True)) for q in arm]
        assert max(gap) > 0.1 and gap[-1] < 0.02, gap
    else:
        assert result.task["shelf_books_fallen"] == 0, result.task
    if kind in ("camera_occluded", "external_push", "sensor_fault", "books_knocked_over"):
        assert result.task["placed"], result.task  # the task itself still succeeds
    if kind == "sensor_fault":
        js = [m for m in msgs["/joint_states"] if start <= _stamp_ns(m) <= end]
        positions = [list(m.ros_msg.position[:6]) for m in js]
        after = [list(m.ros_msg.position[:6]) for m in msgs["/joint_states"] if _stamp_ns(m) > end][:1]
        if result.details["mode"] == "freeze":
            assert all(p == positions[0] for p in positions)  # the reported arm does not move
        else:
            # The drift disappears at the end of the fault: the reported position jumps back.
            jump = max(abs(a - b) for a, b in zip(positions[-1], after[0], strict=True))
            assert jump > 0.1
    if kind == "camera_occluded":
        images = msgs["/camera/image_raw"]
        inside = [bytes(m.ros_msg.data) for m in images if start <= _stamp_ns(m) <= end]
        assert inside, "the occlusion covers at least one frame"


def test_vamos_robot_inspect_lists_the_joints(smoke: Path) -> None:
    vamos_bin = os.environ.get("VAMOS_BIN")
    if not vamos_bin or not Path(vamos_bin).is_file():
        pytest.skip("VAMOS_BIN not set")
    out = subprocess.run([vamos_bin, "robot", "inspect", "--robot", str(smoke / "robot" / "vamos_arm.urdf")],
                         check=True, capture_output=True, text=True).stdout
    info = json.loads(out)
    names = [j["name"] for j in info["joints"] if j["type"] != "fixed"]
    assert names == list(rb.MOVABLE_JOINTS)
    assert rb.CAMERA_FRAME in json.dumps(info)


def _read_png(path: Path) -> np.ndarray:
    """A minimal PNG decoder (8-bit grey, RGB or RGBA, not interlaced) for vamos's output."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        tag, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if tag == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat += body
        pos += 12 + length
    assert header is not None
    width, height, depth, colour, _, _, interlace = header
    assert depth == 8 and interlace == 0 and colour in (0, 2, 6)
    channels = {0: 1, 2: 3, 6: 4}[colour]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8)
    stride = width * channels
    out = np.zeros((height, stride), dtype=np.int32)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        line = raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)].astype(np.int32)
        cur = np.zeros(stride, dtype=np.int32)
        for x in range(stride):  # the filters depend on already decoded bytes of the row
            a = cur[x - channels] if x >= channels else 0
            b = prev[x]
            c = prev[x - channels] if x >= channels else 0
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                pa, pb_, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                pred = a if pa <= pb_ and pa <= pc else (b if pb_ <= pc else c)
            cur[x] = (line[x] + pred) & 0xFF
        out[y] = cur
        prev = cur
    return out.reshape(height, width, channels).astype(np.uint8)


def _dilate(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    padded = np.pad(mask, 1)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            out |= padded[dy:dy + mask.shape[0], dx:dx + mask.shape[1]]
    return out


def test_vamos_render_matches_the_simulated_camera(smoke: Path, tmp_path: Path) -> None:
    """vamos renders the robot from the URDF, camera.json and the bag's joint states; its mask
    must coincide with pybullet's own segmentation of the robot for the same joints."""
    import pybullet as pb

    from vamos.sim.episode import FAR_M, NEAR_M, VFOV_DEG

    vamos_bin = os.environ.get("VAMOS_BIN")
    if not vamos_bin or not Path(vamos_bin).is_file():
        pytest.skip("VAMOS_BIN not set")
    msgs = _read(smoke / "train" / "train_0000.mcap")
    image = msgs["/camera/image_raw"][len(msgs["/camera/image_raw"]) // 2]
    stamp = _stamp_ns(image)
    joints = next(m.ros_msg for m in msgs["/joint_states"] if _stamp_ns(m) == stamp)
    positions = dict(zip(joints.name, joints.position, strict=True))
    (tmp_path / "joints.json").write_text(json.dumps(positions))
    subprocess.run([vamos_bin, "render", "--robot", str(smoke / "robot"), "--joints", str(tmp_path / "joints.json"),
                    "--camera", str(smoke / "camera.json"), "-o", str(tmp_path / "render.png")],
                   check=True, capture_output=True)
    panels = _read_png(tmp_path / "render.png")
    width, height = image.ros_msg.width, image.ros_msg.height
    assert panels.shape[:2] == (height, 3 * width)
    vamos_mask = panels[:, width:2 * width].max(axis=2) > 0  # the depth panel: robot pixels non-zero
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(smoke / "robot" / "vamos_arm.urdf"), useFixedBase=True, physicsClientId=client)
        index = {}
        for i in range(pb.getNumJoints(body, physicsClientId=client)):
            info = pb.getJointInfo(body, i, physicsClientId=client)
            index[info[1].decode()] = i
            index[info[12].decode()] = i
        for name, q in positions.items():
            pb.resetJointState(body, index[name], q, physicsClientId=client)
        st = pb.getLinkState(body, index[rb.CAMERA_FRAME], computeForwardKinematics=True, physicsClientId=client)
        eye = np.array(st[4])
        rot = np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)
        view = pb.computeViewMatrix(eye.tolist(), (eye + rot[:, 2]).tolist(), (-rot[:, 1]).tolist())
        proj = pb.computeProjectionMatrixFOV(VFOV_DEG, width / height, NEAR_M, FAR_M)
        seg = pb.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                physicsClientId=client)[4]
    finally:
        pb.disconnect(client)
    bullet_mask = np.asarray(seg).reshape(height, width) == body
    assert bullet_mask.sum() > 200  # the arm is in view
    iou = (bullet_mask & vamos_mask).sum() / (bullet_mask | vamos_mask).sum()
    assert iou > 0.85, iou
    # Every pixel the two disagree on lies on the other's boundary (within one pixel).
    assert not (bullet_mask & ~_dilate(vamos_mask)).any()
    assert not (vamos_mask & ~_dilate(bullet_mask)).any()


def test_panda_variant_with_meshes(tmp_path: Path) -> None:
    """--robot panda: pybullet_data's franka_panda (meshes copied into the package) does the task."""
    out = tmp_path / "panda"
    # Full-length (the panda misses the slot in some short, fast episodes), tiny images.
    assert main(["generate", "--out", str(out), "--seed", "5", "--robot", "panda", "--train", "1", "--val", "0",
                 "--test-nominal", "0", "--test-anomalous", "0", "--width", "64", "--height", "48", "--workers", "1",
                 "--no-progress"]) == 0
    ds = json.loads((out / "dataset.json").read_text())
    assert ds["robot"] == "robot/vamos_panda.urdf"
    [episode] = ds["episodes"]
    assert episode["task"]["placed"] is True, episode["task"]
    urdf = (out / "robot" / "vamos_panda.urdf").read_text()
    assert "package://meshes/visual/link1.obj" in urdf
    assert (out / "robot" / "meshes" / "visual" / "link1.obj").is_file()
    msgs = _read(out / "train" / "train_0000.mcap")
    assert msgs["/robot_description"][0].ros_msg.data == urdf
    names = list(msgs["/joint_states"][0].ros_msg.name)
    assert names == list(rb.PANDA.movable_joints) and len(names) == 11
    vamos_bin = os.environ.get("VAMOS_BIN")
    if vamos_bin and Path(vamos_bin).is_file():
        info = json.loads(subprocess.run([vamos_bin, "robot", "inspect", "--robot", str(out / "robot")],
                                         check=True, capture_output=True, text=True).stdout)
        assert [j["name"] for j in info["joints"] if j["type"] != "fixed"] == names
        assert info["warnings"] == [] and info["triangles"] > 50_000  # the meshes were loaded


@pytest.mark.parametrize("kind", ["camera_occluded", "external_push", "sensor_fault"])
def test_anomaly_against_its_nominal_twin(kind: str, tmp_path: Path) -> None:
    """These anomalies leave the physics alone: the nominal episode of the same seed, split and
    index moves identically, and the bags differ exactly where the labels say."""
    anomalous = EpisodeSpec("a", "test", 4, kind, 13, 64, 48, 10, True)
    generate_episode(anomalous, tmp_path)
    generate_episode(EpisodeSpec("n", "test", 4, None, 13, 64, 48, 10, True), tmp_path)
    [[start, end]] = json.loads((tmp_path / "a.labels.json").read_text())["intervals_ns"]
    a, n = _read(tmp_path / "a.mcap"), _read(tmp_path / "n.mcap")

    def split(msgs: list, data) -> tuple[list, list]:
        inside = [data(m) for m in msgs if start <= _stamp_ns(m) <= end]
        outside = [data(m) for m in msgs if not start <= _stamp_ns(m) <= end]
        return inside, outside

    def image(m) -> bytes:
        return bytes(m.ros_msg.data)

    def joints(m) -> list[float]:
        return list(m.ros_msg.position)

    img_a_in, img_a_out = split(a["/camera/image_raw"], image)
    img_n_in, img_n_out = split(n["/camera/image_raw"], image)
    js_a_in, js_a_out = split(a["/joint_states"], joints)
    js_n_in, js_n_out = split(n["/joint_states"], joints)
    assert img_a_in and js_a_in
    assert img_a_out == img_n_out and js_a_out == js_n_out  # identical outside the interval
    if kind == "sensor_fault":
        assert img_a_in == img_n_in  # the camera sees the true motion
        assert sum(x != y for x, y in zip(js_a_in, js_n_in, strict=True)) > len(js_a_in) // 2
    else:
        assert js_a_in == js_n_in  # the joint states do not show it
        assert sum(x != y for x, y in zip(img_a_in, img_n_in, strict=True)) > len(img_a_in) // 2


def test_bad_arguments_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["generate", "--out", str(tmp_path / "x"), "--smoke", "--fps", "7"]) == 2
    assert "--fps 7" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["generate", "--out", str(tmp_path / "x"), "--types", "book_falls,nope"])
    assert not (tmp_path / "x").exists()
