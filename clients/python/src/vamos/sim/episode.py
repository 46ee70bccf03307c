"""One simulated episode: the scene, the book-to-shelf task, one optional anomaly, the bag.

Physics runs at 200 Hz; joint states are published at 50 Hz and images (with camera info)
at ``fps``, all stamped with the simulation time in nanoseconds after :data:`EPOCH_NS`.
Everything is drawn from one ``numpy`` generator seeded by ``(seed, split, index, draw)``, so
an episode is the same whichever worker makes it (``draw`` moves on when a drawn pose is
out of the arm's reach). Nominal draws come first: an anomaly that leaves the physics alone
(occlusion, camera shake, sensor fault) has a nominal twin with identical motion.
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb
from pybullet_utils.bullet_client import BulletClient

from vamos.sim import robot as rb
from vamos.sim.bag import BagWriter
from vamos.sim.textures import make_texture, write_png

#: Stamp of simulation time 0: 2024-01-01T00:00:00Z, in ns.
EPOCH_NS = 1_704_067_200_000_000_000
#: Physics rate, Hz.
PHYSICS_HZ = 200
#: Joint state rate, Hz.
JOINT_STATE_HZ = 50
#: Vertical field of view of the head camera, degrees.
VFOV_DEG = 50.0
#: Near and far clipping planes of the render, metres.
NEAR_M, FAR_M = 0.03, 6.0
#: The anomaly types the simulator produces.
ANOMALY_TYPES = ("book_falls", "book_slips", "camera_occluded", "external_push", "books_knocked_over",
                 "sensor_fault", "collision_with_shelf")
#: Dataset splits (their index is part of every episode's seed).
SPLITS = ("train", "val", "test")
#: Scale of phase durations in short (smoke) episodes: ~3 s instead of ~11 s.
SHORT_SCALE = 0.28
#: Range of a book's thickness (the grasped one's and the shelf's), metres.
BOOK_THICKNESS_M = (0.025, 0.045)
_DT = 1.0 / PHYSICS_HZ
_MAX_ATTEMPTS = 8
_CARRY_VIA = 8
_OCCLUDER_HALF_M = 0.12
_DT_NS = 1_000_000_000 // PHYSICS_HZ
# Rest detection of objects set moving by an anomaly (how long an episode runs on).
_MOVING_LIN_MPS = 0.03
_MOVING_ANG_RADPS = 0.3
# The end of such an anomaly's label: the last image at which a watched object is farther
# than this from where it comes to rest (its pose at the episode's end). A pose, not a
# velocity: books lying still jitter in contact above the velocities above, and that
# jitter is not a motion that takes an object anywhere (1 cm at 1 m: 2.6 px at 320x240).
_REST_M = 0.01
_REST_RAD = math.radians(5.0)

# Nominal phase durations, seconds (each varied +-20%).
_PHASES = (("idle", 0.6), ("reach", 1.6), ("descend", 0.8), ("close", 0.5), ("lift", 0.8), ("carry", 2.2),
           ("lower", 0.8), ("open", 0.4), ("retract", 0.8), ("return", 1.6), ("rest", 0.6))


class SimError(Exception):
    """A simulation set-up that cannot be run (bad rates, unknown anomaly type)."""


class UnreachableError(SimError):
    """A drawn pose the arm cannot reach (the episode is drawn again)."""


@dataclass(frozen=True)
class EpisodeSpec:
    """What to generate: name, split, anomaly (None = nominal), seed, image size and rate."""

    name: str
    split: str
    index: int
    anomaly: str | None
    seed: int
    width: int = 640
    height: int = 480
    fps: int = 10
    short: bool = False
    #: Robot: "primitive" (the URDF-primitive arm) or "panda" (pybullet_data's franka_panda).
    robot: str = "primitive"
    #: Camera: "head" (on the pan-tilt head), "fixed" (fixed to the world) or "wrist" (on
    #: the arm; robot.CAMERAS).
    camera: str = "head"
    #: Also record a depth image registered to every image (``bag.DEPTH_TOPIC``).
    depth: bool = False
    #: Draw number: a draw whose poses the arm cannot reach is replaced by the next one.
    attempt: int = 0

    def rng(self) -> np.random.Generator:
        """The episode's generator, from (seed, split, index, attempt)."""
        return np.random.default_rng(
            np.random.SeedSequence([self.seed, SPLITS.index(self.split), self.index, self.attempt]))


@dataclass
class EpisodeResult:
    """What one episode produced."""

    name: str
    split: str
    anomaly: str | None
    duration_s: float
    images: int
    joint_states: int
    intervals_ns: list[list[int]]
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    attempt: int = 0
    #: Where the book ended, whether it stands in its slot (``placed``), how many of the
    #: shelf's standing books lie tilted by more than 30 degrees at the end.
    task: dict[str, Any] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)


def intrinsics(width: int, height: int) -> tuple[float, float, float, float]:
    """``fx, fy, cx, cy`` of the rendered camera (square pixels, centred; pixel (0, 0) is the
    centre of the top-left pixel, as CameraInfo's K)."""
    f = (height / 2.0) / math.tan(math.radians(VFOV_DEG) / 2.0)
    return f, f, (width - 1) / 2.0, (height - 1) / 2.0


def camera_spec(width: int, height: int, camera: str = "head") -> dict[str, Any]:
    """The camera description in vamos's ``camera.json`` format (``CameraSpec``)."""
    fx, fy, cx, cy = intrinsics(width, height)
    return {"frame": rb.camera_frame(camera), "convention": "optical", "width": width, "height": height,
            "fx": fx, "fy": fy, "cx": cx, "cy": cy}


def _min_jerk(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10 - 15 * s + 6 * s * s)


def _min_jerk_rate(s: float) -> float:
    if s <= 0.0 or s >= 1.0:
        return 0.0
    return 30 * s * s * (1 - s) ** 2


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    out: np.ndarray = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
    return out


def _quat_from_matrix(m: np.ndarray) -> list[float]:
    """(x, y, z, w) of a rotation matrix."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    return q


@dataclass
class _Segment:
    """Arm motion from q0 to q1 over [t0, t1] (minimum jerk); fingers likewise. With `via`
    (joint positions at evenly spaced points of a Cartesian path) the arm follows the
    piecewise-linear joint path q0 -> via... -> q1 under the same minimum-jerk timing."""

    name: str
    t0: float
    t1: float
    q0: np.ndarray
    q1: np.ndarray
    g0: float
    g1: float
    via: list[np.ndarray] = field(default_factory=list)

    def path(self, k: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint position and d(position)/dk at path parameter k in [0, 1]."""
        points = [self.q0, *self.via, self.q1]
        n = len(points) - 1
        i = min(int(k * n), n - 1)
        local = k * n - i
        step = points[i + 1] - points[i]
        return points[i] + local * step, step * n


class _Plan:
    def __init__(self) -> None:
        self.segments: list[_Segment] = []

    def add(self, name: str, duration: float, q1: np.ndarray, g1: float,
            via: list[np.ndarray] | None = None) -> _Segment:
        if self.segments:
            last = self.segments[-1]
            t0, q0, g0 = last.t1, last.q1, last.g1
        else:
            t0, q0, g0 = 0.0, q1, g1
        seg = _Segment(name, t0, t0 + duration, q0, q1, g0, g1, via or [])
        self.segments.append(seg)
        return seg

    @property
    def end(self) -> float:
        return self.segments[-1].t1

    def phase(self, name: str) -> _Segment:
        return next(s for s in self.segments if s.name == name)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Arm position, arm velocity, finger target at time t."""
        seg = self.segments[-1]
        for s in self.segments:
            if t < s.t1:
                seg = s
                break
        dur = seg.t1 - seg.t0
        u = (t - seg.t0) / dur if dur > 0 else 1.0
        k = _min_jerk(u)
        q, dq_dk = seg.path(k)
        qd = dq_dk * (_min_jerk_rate(u) / dur if dur > 0 else 0.0)
        return q, qd, seg.g0 + k * (seg.g1 - seg.g0)


class Episode:
    """Builds the world of one episode in its own pybullet client and runs it."""

    def __init__(self, spec: EpisodeSpec, texture_dir: Path) -> None:
        if spec.fps <= 0 or PHYSICS_HZ % spec.fps != 0:
            raise SimError(f"--fps {spec.fps} must divide the physics rate {PHYSICS_HZ} Hz")
        if spec.robot not in rb.ROBOTS:
            raise SimError(f"unknown robot {spec.robot!r}; known: {', '.join(rb.ROBOTS)}")
        if spec.anomaly is not None and spec.anomaly not in ANOMALY_TYPES:
            raise SimError(f"unknown anomaly type {spec.anomaly!r}; known: {', '.join(ANOMALY_TYPES)}")
        self.spec = spec
        self.rng = spec.rng()
        self.scale = SHORT_SCALE if spec.short else 1.0
        self.tex_dir = texture_dir
        self.p = BulletClient(connection_mode=pb.DIRECT)
        p = self.p
        p.setGravity(0, 0, -9.81)
        p.setPhysicsEngineParameter(fixedTimeStep=_DT, numSolverIterations=60, deterministicOverlappingPairs=1)
        self._tex_count = 0
        self._frozen: tuple[list[float], list[float], list[float]] | None = None
        self._build_scene()
        self._load_robot()

    # ----- scene -----------------------------------------------------------------------
    def _texture(self, kind: str, rgb: Sequence[float], size: int = 256, scale: int = 1) -> int:
        path = self.tex_dir / f"tex_{self._tex_count:03d}.png"
        self._tex_count += 1
        write_png(path, make_texture(self.rng, kind, rgb, size, scale))
        return int(self.p.loadTexture(str(path)))

    def _box(self, half: tuple[float, float, float], pos: tuple[float, float, float], tex: int,
             mass: float = 0.0, yaw: float = 0.0, rgba: tuple[float, ...] = (1, 1, 1, 1),
             friction: float = 0.8) -> int:
        p = self.p
        col = p.createCollisionShape(pb.GEOM_BOX, halfExtents=half)
        vis = p.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba)
        body = int(p.createMultiBody(mass, col, vis, pos, p.getQuaternionFromEuler((0, 0, yaw))))
        p.changeVisualShape(body, -1, textureUniqueId=tex)
        p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def _book_dims(self) -> tuple[float, float, float]:
        r = self.rng
        return float(r.uniform(*BOOK_THICKNESS_M)), float(r.uniform(0.13, 0.17)), float(r.uniform(0.19, 0.24))

    def _book_colour(self) -> tuple[float, float, float]:
        hue = self.rng.uniform(0, 1)
        c = np.array([abs(hue * 6 - 3) - 1, 2 - abs(hue * 6 - 2), 2 - abs(hue * 6 - 4)]).clip(0, 1)
        c = 0.25 + 0.65 * c * self.rng.uniform(0.6, 1.0)
        return float(c[0]), float(c[1]), float(c[2])

    def _build_scene(self) -> None:
        r = self.rng
        floor_kind = str(r.choice(["checker", "noise", "wood"]))
        floor_rgb = tuple(float(x) for x in r.uniform(0.45, 0.8, 3))
        self._box((3.0, 3.0, 0.01), (0.5, 0.0, -0.01), self._texture(floor_kind, floor_rgb, 512, scale=12))
        wall_rgb = tuple(float(x) for x in r.uniform(0.55, 0.9, 3))
        wall_kind = str(r.choice(["plaster", "noise", "stripes"]))
        wall_tex = self._texture(wall_kind, wall_rgb, 512, scale=8)
        self._box((0.02, 3.0, 1.5), (1.25, 0.0, 1.5), wall_tex)
        self._box((3.0, 0.02, 1.5), (0.5, 1.6, 1.5), wall_tex)
        wood = self._texture("wood", tuple(float(x) for x in r.uniform([0.45, 0.3, 0.15], [0.75, 0.55, 0.35])))
        # Table for the book to pick.
        self.table_top_z = float(r.uniform(0.38, 0.42))
        self._box((0.2, 0.29, self.table_top_z / 2), (0.5, -0.41, self.table_top_z / 2), wood)
        # Shelf: sides, back, lower and upper boards; open above the upper board.
        shelf_wood = self._texture("wood", tuple(float(x) for x in r.uniform([0.35, 0.25, 0.15], [0.7, 0.5, 0.3])))
        self.board_z = float(r.uniform(0.53, 0.57))
        self.shelf_front_x, self.shelf_back_x = 0.42, 0.72
        cx, depth = (self.shelf_front_x + self.shelf_back_x) / 2, self.shelf_back_x - self.shelf_front_x
        y0, y1 = 0.12, 0.95
        self.shelf_y = (y0, y1)
        bt = 0.025
        self.shelf_bodies = [
            self._box((depth / 2, 0.015, self.board_z / 2), (cx, y0 - 0.015, self.board_z / 2), shelf_wood),
            self._box((depth / 2, 0.015, self.board_z / 2), (cx, y1 + 0.015, self.board_z / 2), shelf_wood),
            self._box((0.01, (y1 - y0) / 2 + 0.03, self.board_z / 2 + 0.2),
                      (self.shelf_back_x + 0.01, (y0 + y1) / 2, self.board_z / 2 + 0.2), shelf_wood),
            self._box((depth / 2, (y1 - y0) / 2, bt / 2), (cx, (y0 + y1) / 2, self.board_z - bt / 2), shelf_wood),
            self._box((depth / 2, (y1 - y0) / 2, bt / 2), (cx, (y0 + y1) / 2, 0.18), shelf_wood),
        ]
        # Static books on the lower level (texture and realism).
        y = y0 + 0.02
        while True:
            t, w, h = self._book_dims()
            h = min(h, self.board_z - bt - 0.2 - 0.01)
            if y + t > y1 - 0.02:
                break
            self._box((w / 2, t / 2, h / 2), (self.shelf_front_x + w / 2 + 0.01, y + t / 2, 0.18 + bt / 2 + h / 2),
                      self._texture("stripes", self._book_colour(), 128))
            y += t + float(r.uniform(0.0, 0.01))
        # The book to place: standing on the table.
        self.book_t, self.book_w, self.book_h = self._book_dims()
        self.book_pos = np.array([r.uniform(0.45, 0.55), r.uniform(-0.45, -0.3), self.table_top_z + self.book_h / 2])
        self.book_yaw = float(r.uniform(-0.25, 0.25))
        self.book = self._box((self.book_w / 2, self.book_t / 2, self.book_h / 2), tuple(self.book_pos),
                              self._texture(str(r.choice(["stripes", "noise"])), self._book_colour(), 128),
                              mass=float(r.uniform(0.3, 0.6)), yaw=self.book_yaw, friction=1.0)
        # The slot on the upper board and the row of standing books beside it.
        self.slot_y = float(r.uniform(0.28, 0.36))
        self.row_x = cx + float(r.uniform(-0.02, 0.02))
        y = self.slot_y + self.book_t / 2 + float(r.uniform(0.025, 0.035))
        self.row_books: list[int] = []
        self.row_y = (y, y)
        for _ in range(int(r.integers(4, 7))):
            t, w, h = self._book_dims()
            self.row_books.append(self._box((w / 2, t / 2, h / 2), (self.row_x, y + t / 2, self.board_z + h / 2),
                                            self._texture("stripes", self._book_colour(), 128),
                                            mass=float(r.uniform(0.3, 0.6)), friction=0.9))
            y += t + float(r.uniform(0.002, 0.01))
        self.row_y = (self.row_y[0], y)
        # Lighting.
        az, el = r.uniform(-math.pi, math.pi), r.uniform(math.radians(35), math.radians(75))
        self.light = {
            "lightDirection": [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)],
            "lightColor": [float(x) for x in r.uniform(0.9, 1.0, 3)],
            "lightAmbientCoeff": float(r.uniform(0.55, 0.75)),
            "lightDiffuseCoeff": float(r.uniform(0.35, 0.55)),
            "lightSpecularCoeff": float(r.uniform(0.03, 0.12)),
        }
        self.texture_choice = {"floor": floor_kind, "wall": wall_kind}

    def _load_robot(self) -> None:
        p = self.p
        self.model = rb.ROBOTS[self.spec.robot]
        path = self.model.write_package(self.tex_dir / "robot", self.spec.camera)
        self.urdf = path.read_text()
        self.robot = int(p.loadURDF(str(path), useFixedBase=True, flags=pb.URDF_USE_INERTIA_FROM_FILE))
        self.joint = {}
        self.link = {}
        for i in range(p.getNumJoints(self.robot)):
            info = p.getJointInfo(self.robot, i)
            self.joint[info[1].decode()] = i
            self.link[info[12].decode()] = i
        self.arm = [self.joint[n] for n in self.model.arm_joints]
        self.fingers = [self.joint[n] for n in self.model.finger_joints]
        self.head = [self.joint[n] for n in rb.HEAD_JOINTS]
        self.movable = [self.joint[n] for n in self.model.movable_joints]
        self.n_arm = len(self.arm)
        self.tool = self.link[self.model.tool_link]
        self.camera_frame = rb.camera_frame(self.spec.camera)
        self.camera = self.link[self.camera_frame]
        self.limits = [p.getJointInfo(self.robot, j)[8:10] for j in self.movable]
        self.efforts = [p.getJointInfo(self.robot, j)[10] for j in self.movable]
        # The grasped book is held by a fixed constraint (a friction grasp is not stable in
        # pybullet), so it never collides with the hand. Its fingers do touch it, as a real
        # gripper's do: closing on it they stop at its faces and press with their force limit,
        # so the joint states read the book's width and the grip force, and a grasp that is
        # lost shows there (the fingers close on nothing). Their contact is frictionless, so
        # the constraint alone decides whether the book is held.
        for link in self.model.gripper_links:
            if self.link[link] not in self.fingers:  # a joint's index is its child link's
                p.setCollisionFilterPair(self.robot, self.book, self.link[link], -1, 0)
        for finger in self.fingers:
            p.changeDynamics(self.robot, finger, lateralFriction=0.0, spinningFriction=0.0, rollingFriction=0.0)

    # ----- planning --------------------------------------------------------------------
    def _ik(self, pos: np.ndarray, yaw: float, seed: np.ndarray) -> np.ndarray:
        """Arm joints putting the tool at `pos`, pointing down, fingers across `yaw`."""
        p = self.p
        orn = _quat_from_matrix(_rot_z(yaw) @ np.diag([-1.0, 1.0, -1.0]))
        lower = [lo for lo, _ in self.limits]
        upper = [hi for _, hi in self.limits]
        ranges = [hi - lo for lo, hi in self.limits]
        rest = list(seed) + [0.0] * (len(self.movable) - self.n_arm)
        q = np.array(seed, dtype=float)
        best, best_err = q, float("inf")
        for _ in range(8):
            for j, v in zip(self.arm, q, strict=True):
                p.resetJointState(self.robot, j, float(v))
            sol = p.calculateInverseKinematics(self.robot, self.tool, [float(x) for x in pos], orn,
                                               lowerLimits=lower, upperLimits=upper, jointRanges=ranges,
                                               restPoses=rest, maxNumIterations=200, residualThreshold=1e-6)
            q = np.array(sol[:self.n_arm])
            for j, v in zip(self.arm, q, strict=True):
                p.resetJointState(self.robot, j, float(v))
            got = np.array(p.getLinkState(self.robot, self.tool, computeForwardKinematics=True)[4])
            err = float(np.linalg.norm(got - pos))
            if err < best_err:
                best, best_err = q, err
            if err < 1e-3:
                break
        if best_err > 0.01:
            raise UnreachableError(f"tool position {pos.round(3).tolist()} unreachable (IK error {best_err:.3f} m)")
        return best

    def _duration(self, nominal: float) -> float:
        return nominal * float(self.rng.uniform(0.8, 1.2)) * self.scale

    def plan(self) -> None:
        """The arm's motion, the grasp/release times and the anomaly's parameters."""
        r = self.rng
        kind = self.spec.anomaly
        # Every nominal draw comes before any anomaly-specific one, so an episode whose
        # anomaly does not change the physics (camera_occluded, external_push, sensor_fault)
        # has a nominal twin (same seed, split, index; no anomaly) with the same motion.
        self.head_sway = float(r.uniform(0.03, 0.08))
        self.head_period = float(r.uniform(4.0, 8.0)) * self.scale
        durations = {name: self._duration(d) for name, d in _PHASES}
        home = np.array(self.model.home) + r.uniform(-0.05, 0.05, self.n_arm)
        grasp_depth = float(r.uniform(0.03, 0.045))
        top = self.book_pos + np.array([0, 0, self.book_h / 2])
        grasp = top - np.array([0, 0, grasp_depth])
        hang = self.book_h - grasp_depth  # tool height above the book's bottom
        place_x = self.row_x + float(r.uniform(-0.01, 0.01))
        place_yaw = float(r.uniform(-0.04, 0.04))
        if kind == "book_falls":
            # Released with its centre over the front edge of the board: it tips off.
            place_x = self.shelf_front_x + float(r.uniform(-0.03, 0.0))
        place_drop = 0.004
        if kind == "collision_with_shelf":
            # The arm lowers the book too far (onto the board): the book hits it, the board
            # pushes back and the book is jammed down.
            place_drop = -float(r.uniform(0.03, 0.05))
        place = np.array([place_x, self.slot_y, self.board_z + place_drop + hang])
        lift_h = float(r.uniform(0.27, 0.32))
        yaw_book = self.book_yaw
        q_pre = self._ik(grasp + [0, 0, 0.12], yaw_book, home)
        q_grasp = self._ik(grasp, yaw_book, q_pre)
        q_lift = self._ik(grasp + [0, 0, lift_h], yaw_book, q_grasp)
        # Carry along the straight line from above the table to above the slot (a joint-space
        # arc would swing the book into the shelf's back panel).
        lift_pos, pre_place_pos = grasp + [0, 0, lift_h], place + [0, 0, 0.13]
        via, q_via = [], q_lift
        for k in range(1, _CARRY_VIA):
            f = k / _CARRY_VIA
            q_via = self._ik(lift_pos + f * (pre_place_pos - lift_pos), yaw_book + f * (place_yaw - yaw_book), q_via)
            via.append(q_via)
        q_pre_place = self._ik(place + [0, 0, 0.13], place_yaw, q_via)
        q_place = self._ik(place, place_yaw, q_pre_place)
        q_retract = self._ik(place + [0, 0, 0.14], place_yaw, q_place)
        # A grasp commands the fingers shut; they stop on the book's faces.
        closed = 0.0
        op = self.model.finger_open_m
        plan = _Plan()
        plan.add("idle", durations["idle"], home, op)
        plan.add("reach", durations["reach"], q_pre, op)
        plan.add("descend", durations["descend"], q_grasp, op)
        plan.add("close", durations["close"], q_grasp, closed)
        plan.add("lift", durations["lift"], q_lift, closed)
        self.events: dict[str, float] = {}
        self.anomaly_info: dict[str, Any] = {}
        plan.add("carry", durations["carry"], q_pre_place, closed, via=via)
        if kind == "books_knocked_over":
            # A detour from above the slot: down beside the row of standing books, a sweep
            # along the row (the held book pushes them over), up, back above the slot.
            z = self.board_z + float(r.uniform(0.1, 0.13)) + hang
            b = np.array([self.row_x, self.slot_y, z])
            c = np.array([self.row_x + float(r.uniform(-0.015, 0.015)), self.row_y[1] + 0.03, z])
            q_b = self._ik(b, place_yaw, q_pre_place)
            q_c = self._ik(c, place_yaw, q_b)
            q_up = self._ik(c + [-0.03, -0.08, 0.14], place_yaw, q_c)
            down = plan.add("detour_down", self._duration(0.7), q_b, closed)
            plan.add("sweep", self._duration(0.7), q_c, closed)
            plan.add("detour_up", self._duration(0.7), q_up, closed)
            back = plan.add("detour_back", self._duration(1.0), q_pre_place, closed)
            # The anomalous motion is the whole detour: the arm is off its task until it is
            # back above the slot (and the books until they rest).
            self.anomaly_info = {"onset": down.t0, "motion_end": back.t1, "watch": list(self.row_books)}
        plan.add("lower", durations["lower"], q_place, closed)
        opening = plan.add("open", durations["open"], q_place, op)
        plan.add("retract", durations["retract"], q_retract, op)
        plan.add("return", durations["return"], home, op)
        plan.add("rest", durations["rest"], home, op)
        self.plan_ = plan
        self.events["attach"] = plan.phase("close").t1
        self.events["release"] = opening.t0
        self.home = home
        # Anomaly parameters.
        motion0, motion1 = plan.phase("reach").t0, plan.phase("return").t1
        # A book that falls, slips or is jammed may knock the shelf's books: one it touches
        # after the onset is watched too (the label lasts until it is at rest as well).
        knock = {"watch": [self.book], "may_knock": list(self.row_books)}
        if kind == "book_falls":
            self.anomaly_info = {"onset": opening.t0, "motion_end": opening.t0, **knock}
        elif kind == "book_slips":
            carry = plan.phase("carry")
            t = carry.t0 + float(r.uniform(0.2, 0.6)) * (carry.t1 - carry.t0)
            self.events["release"] = t
            self.anomaly_info = {"onset": t, "motion_end": t, **knock}
        elif kind == "collision_with_shelf":
            lower = plan.phase("lower")
            # Contact starts when the book's bottom reaches the board (computed in the run).
            self.anomaly_info = {"onset": None, "contact_after": lower.t0, "motion_end": opening.t1,
                                 **knock}
        elif kind == "camera_occluded":
            t0 = float(r.uniform(motion0, motion1 - 3.0 * self.scale))
            t_in, hold, t_out = (self._duration(x) for x in (0.4, 1.8, 0.4))
            full = bool(r.random() < 0.5)
            self.anomaly_info = {"onset": t0, "motion_end": t0 + t_in + hold + t_out, "t_in": t_in, "hold": hold,
                                 "t_out": t_out, "full": full, "side": float(r.choice([-1.0, 1.0])),
                                 "cover": float(r.uniform(0.35, 0.7)), "watch": []}
            tex = self._texture(str(r.choice(["noise", "stripes", "checker"])),
                                tuple(float(x) for x in r.uniform(0.3, 0.9, 3)), 256, scale=8)
            vis = self.p.createVisualShape(pb.GEOM_BOX, halfExtents=[_OCCLUDER_HALF_M, _OCCLUDER_HALF_M, 0.002])
            self.occluder = int(self.p.createMultiBody(0, -1, vis, [0, 0, -5]))
            self.p.changeVisualShape(self.occluder, -1, textureUniqueId=tex)
        elif kind == "external_push":
            t0 = float(r.uniform(motion0, motion1 - 2.0 * self.scale))
            tau = float(r.uniform(0.25, 0.45)) * max(self.scale, 0.5)
            self.anomaly_info = {"onset": t0, "motion_end": t0 + tau * math.log(20.0), "tau": tau,
                                 "amp_rad": float(r.uniform(0.025, 0.05)), "amp_m": float(r.uniform(0.01, 0.03)),
                                 "freq_hz": float(r.uniform(3.0, 6.0)),
                                 "axis": r.normal(size=3).tolist(), "dir": r.normal(size=3).tolist(), "watch": []}
        elif kind == "sensor_fault":
            t0 = float(r.uniform(motion0, motion1 - 3.0 * self.scale))
            dur = self._duration(2.2)
            mode = str(r.choice(["freeze", "drift"]))
            joints = sorted(int(j) for j in r.choice(self.n_arm, size=int(r.integers(1, 4)), replace=False))
            rates = [float(r.choice([-1, 1]) * r.uniform(0.25, 0.5)) / max(self.scale, 0.5) for _ in joints]
            self.anomaly_info = {"onset": t0, "motion_end": t0 + dur, "mode": mode, "joints": joints,
                                 "rates_radps": rates, "watch": []}

    # ----- running ---------------------------------------------------------------------
    def _camera_pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        st = self.p.getLinkState(self.robot, self.camera, computeForwardKinematics=True)
        pos = np.array(st[4])
        rot = np.array(self.p.getMatrixFromQuaternion(st[5])).reshape(3, 3)
        a = self.anomaly_info
        if self.spec.anomaly == "external_push" and a["onset"] <= t <= a["motion_end"]:
            dt = t - a["onset"]
            env = math.exp(-dt / a["tau"]) * math.sin(2 * math.pi * a["freq_hz"] * dt)
            rot = rot @ _rot_axis(np.array(a["axis"]), a["amp_rad"] * env)
            d = np.array(a["dir"])
            pos = pos + rot @ (d / np.linalg.norm(d)) * a["amp_m"] * env
        return pos, rot

    def _place_occluder(self, t: float, pos: np.ndarray, rot: np.ndarray) -> None:
        a = self.anomaly_info
        t0 = a["onset"]
        if not (t0 <= t <= a["motion_end"]):
            self.p.resetBasePositionAndOrientation(self.occluder, [0, 0, -5], [0, 0, 0, 1])
            return
        if t < t0 + a["t_in"]:
            k = _min_jerk((t - t0) / a["t_in"])
        elif t <= t0 + a["t_in"] + a["hold"]:
            k = 1.0
        else:
            k = 1.0 - _min_jerk((t - t0 - a["t_in"] - a["hold"]) / a["t_out"])
        depth = 0.12
        half_w = depth * math.tan(math.radians(VFOV_DEG) / 2) * self.spec.width / self.spec.height
        # Out of view at k = 0; at k = 1 covering everything (full) or a `cover` fraction.
        final = 0.0 if a["full"] else a["side"] * (_OCCLUDER_HALF_M + half_w - 2 * a["cover"] * half_w)
        start = a["side"] * (_OCCLUDER_HALF_M + half_w + 0.02)
        x = start + k * (final - start)
        centre = pos + rot @ np.array([x, 0.02 * math.sin(3 * t), depth])
        self.p.resetBasePositionAndOrientation(self.occluder, centre.tolist(), _quat_from_matrix(rot))

    def _render(self, t: float) -> tuple[bytes, bytes | None]:
        """The rgb8 image at `t` and, for a spec with depth, its 16UC1 depth image
        (millimetres along the optical axis; 0 where the ray meets nothing before the far
        plane)."""
        w, h = self.spec.width, self.spec.height
        pos, rot = self._camera_pose(t)
        if self.spec.anomaly == "camera_occluded":
            self._place_occluder(t, pos, rot)
        view = self.p.computeViewMatrix(pos.tolist(), (pos + rot[:, 2]).tolist(), (-rot[:, 1]).tolist())
        proj = self.p.computeProjectionMatrixFOV(VFOV_DEG, w / h, NEAR_M, FAR_M)
        out = self.p.getCameraImage(w, h, view, proj, renderer=pb.ER_TINY_RENDERER, shadow=0,
                                    flags=pb.ER_NO_SEGMENTATION_MASK, **self.light)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(h, w, 4)
        if not self.spec.depth:
            return rgba[:, :, :3].tobytes(), None
        # OpenGL's depth buffer (0..1, non-linear) to metres along the optical axis.
        d = np.asarray(out[3], dtype=np.float64).reshape(h, w)
        z = FAR_M * NEAR_M / (FAR_M - (FAR_M - NEAR_M) * d)
        mm = np.where(d < 1.0 - 1e-6, np.clip(np.round(z * 1000.0), 1, 65535), 0).astype("<u2")
        return rgba[:, :, :3].tobytes(), mm.tobytes()

    def _head_target(self, tool: np.ndarray, t: float) -> tuple[float, float]:
        centre = np.array([0.55, 0.1, self.board_z - 0.1])
        look = centre + 0.3 * (tool - centre)
        origin = np.array(rb.HEAD_PAN_XYZ) + np.array([0.0, 0.0, rb.HEAD_TILT_DZ])
        d = look - origin
        pan = math.atan2(d[1], d[0]) + self.head_sway * math.sin(2 * math.pi * t / self.head_period)
        tilt = math.atan2(-d[2], math.hypot(d[0], d[1]))
        return pan, tilt

    def _reported(self, t: float, pos: list[float], vel: list[float],
                  eff: list[float]) -> tuple[list[float], list[float], list[float]]:
        a = self.anomaly_info
        if self.spec.anomaly != "sensor_fault" or not (a["onset"] <= t <= a["motion_end"]):
            return pos, vel, eff
        if a["mode"] == "freeze":
            if self._frozen is None:
                self._frozen = (list(pos), [0.0] * len(vel), list(eff))
            return self._frozen
        pos, vel = list(pos), list(vel)
        for j, rate in zip(a["joints"], a["rates_radps"], strict=True):
            pos[j] += rate * (t - a["onset"])
            vel[j] += rate
        return pos, vel, eff

    def run(self, out_dir: Path) -> EpisodeResult:
        """Simulates, writes ``<name>.mcap`` and ``<name>.labels.json``; returns the summary."""
        p, spec = self.p, self.spec
        self.plan()
        self._frozen = None
        # Initial state.
        q0, _, g0 = self.plan_.at(0.0)
        for j, v in zip(self.arm, q0, strict=True):
            p.resetJointState(self.robot, j, float(v))
        for j in self.fingers:
            p.resetJointState(self.robot, j, g0)
        tool0 = np.array(p.getLinkState(self.robot, self.tool, computeForwardKinematics=True)[4])
        pan, tilt = self._head_target(tool0, 0.0)
        p.resetJointState(self.robot, self.head[0], pan)
        p.resetJointState(self.robot, self.head[1], tilt)
        p.resetBasePositionAndOrientation(self.book, self.book_pos.tolist(),
                                          p.getQuaternionFromEuler((0, 0, self.book_yaw)))
        for _ in range(40):  # settle the books (robot held), then reset time to 0
            p.stepSimulation()
        nominal_end = self.plan_.end
        max_extra = max(4.0 * self.scale, 1.5)
        img_every = PHYSICS_HZ // spec.fps
        js_every = PHYSICS_HZ // JOINT_STATE_HZ
        bag_path = out_dir / f"{spec.name}.mcap"
        bag = BagWriter(bag_path)
        fx, fy, cx, cy = intrinsics(spec.width, spec.height)
        bag.robot_description(EPOCH_NS, self.urdf)
        names = list(self.model.movable_joints)
        constraint: int | None = None
        released = False
        watch = list(self.anomaly_info.get("watch", []))
        may_knock = self.anomaly_info.get("may_knock", [])
        tracked = watch + may_knock
        last_moving = None
        # (t, [(position, orientation)] per tracked body) at every image from the onset on.
        watched_poses: list[tuple[float, list[tuple[Any, Any]]]] = []
        contact_t: float | None = None
        n_images = n_js = 0
        step = 0
        tool_pos = tool0
        head_filtered = np.array([pan, tilt])
        while True:
            t = step * _DT
            if t > nominal_end + 1e-9:
                still = last_moving is None or t - last_moving > 0.4
                if step % img_every == 0 and (still or t > nominal_end + max_extra):
                    break
            q, qd, g = self.plan_.at(t)
            p.setJointMotorControlArray(self.robot, self.arm, pb.POSITION_CONTROL, targetPositions=q.tolist(),
                                        targetVelocities=qd.tolist(), forces=self.efforts[:self.n_arm],
                                        positionGains=[0.2] * self.n_arm, velocityGains=[1.0] * self.n_arm)
            p.setJointMotorControlArray(self.robot, self.fingers, pb.POSITION_CONTROL, targetPositions=[g, g],
                                        forces=self.efforts[self.n_arm:self.n_arm + 2])
            target = np.array(self._head_target(tool_pos, t))
            head_filtered += (target - head_filtered) * min(1.0, _DT / 0.5)
            p.setJointMotorControlArray(self.robot, self.head, pb.POSITION_CONTROL,
                                        targetPositions=head_filtered.tolist(),
                                        forces=self.efforts[self.n_arm + 2:self.n_arm + 4])
            if constraint is None and not released and t >= self.events["attach"]:
                constraint = self._attach()
            if constraint is not None and t >= self.events["release"]:
                p.removeConstraint(constraint)
                constraint, released = None, True
            if step % js_every == 0:
                states = p.getJointStates(self.robot, self.movable)
                pos = [s[0] for s in states]
                vel = [s[1] for s in states]
                eff = [s[3] for s in states]
                pos, vel, eff = self._reported(t, pos, vel, eff)
                bag.joint_state(EPOCH_NS + step * _DT_NS, names, pos, vel, eff)
                n_js += 1
            if step % img_every == 0:
                stamp = EPOCH_NS + step * _DT_NS
                rgb, depth = self._render(t)
                bag.image(stamp, self.camera_frame, rgb, spec.width, spec.height)
                if depth is not None:
                    bag.depth(stamp, self.camera_frame, depth, spec.width, spec.height)
                bag.camera_info(stamp, self.camera_frame, spec.width, spec.height, fx, fy, cx, cy)
                n_images += 1
                last_image_t = t
                if tracked and self.anomaly_info.get("onset") is not None and t >= self.anomaly_info["onset"]:
                    watched_poses.append((t, [p.getBasePositionAndOrientation(b) for b in tracked]))
            p.stepSimulation()
            step += 1
            tool_pos = np.array(p.getLinkState(self.robot, self.tool)[4])
            onset = self.anomaly_info.get("onset")
            if spec.anomaly == "collision_with_shelf" and contact_t is None \
                    and t >= self.anomaly_info["contact_after"] \
                    and any(p.getContactPoints(self.book, b) for b in self.shelf_bodies):
                contact_t = t
                self.anomaly_info["onset"] = onset = t
            if onset is not None and t >= onset:
                if may_knock:
                    touching = {c[2] for c in p.getContactPoints(bodyA=self.book)}
                    watch += [b for b in may_knock if b in touching and b not in watch]
                for body in watch:
                    lin, ang = p.getBaseVelocity(body)
                    if np.linalg.norm(lin) > _MOVING_LIN_MPS or np.linalg.norm(ang) > _MOVING_ANG_RADPS:
                        last_moving = step * _DT
        bag.close()
        intervals: list[list[int]] = []
        details: dict[str, Any] = {}
        if spec.anomaly is not None:
            a = self.anomaly_info
            onset = a["onset"]
            if onset is None:  # collision_with_shelf without contact: the jam never happened
                onset = a["contact_after"]
            knocked = [i for i, body in enumerate(tracked) if body in watch]
            rest = _last_away_from_rest([(t, [poses[i] for i in knocked]) for t, poses in watched_poses])
            end = max(a["motion_end"], rest or onset)
            end = min(end, last_image_t)
            intervals = [[EPOCH_NS + round(onset * 1e9), EPOCH_NS + round(end * 1e9)]]
            details = {k: v for k, v in a.items() if k not in ("watch", "may_knock")}
            # The label's end by the rule used until 2026-12-07 (the last physics step at which
            # a watched object moved faster than _MOVING_*), for comparisons with older figures.
            details["end_by_velocity"] = min(max(a["motion_end"], last_moving or onset), last_image_t)
            if spec.anomaly == "collision_with_shelf":
                details["contact"] = contact_t is not None
        labels = {"episode": spec.name, "anomalous": spec.anomaly is not None, "anomaly_type": spec.anomaly,
                  "intervals_ns": intervals}
        (out_dir / f"{spec.name}.labels.json").write_text(json.dumps(labels, indent=2) + "\n")
        # Where the book ended: standing in the slot on the board (the task done) or not.
        book_pos, book_orn = p.getBasePositionAndOrientation(self.book)
        up = np.array(p.getMatrixFromQuaternion(book_orn)).reshape(3, 3)[:, 2]
        target = np.array([self.row_x, self.slot_y, self.board_z + self.book_h / 2])
        placed = bool(np.linalg.norm(np.array(book_pos[:2]) - target[:2]) < 0.06
                      and abs(book_pos[2] - target[2]) < 0.02 and up[2] > math.cos(math.radians(15)))
        fallen = 0
        for body in self.row_books:
            orn = p.getBasePositionAndOrientation(body)[1]
            fallen += int(np.array(p.getMatrixFromQuaternion(orn))[8] < math.cos(math.radians(30)))
        task = {"book_final_m": [round(float(x), 4) for x in book_pos],
                "slot_m": [round(float(x), 4) for x in target], "placed": placed,
                "shelf_books_fallen": fallen, "shelf_books": len(self.row_books)}
        return EpisodeResult(spec.name, spec.split, spec.anomaly, round(last_image_t, 6), n_images, n_js,
                             intervals, details=details, task=task)

    def _attach(self) -> int:
        p = self.p
        tool = p.getLinkState(self.robot, self.tool, computeForwardKinematics=True)
        book_pos, book_orn = p.getBasePositionAndOrientation(self.book)
        inv_pos, inv_orn = p.invertTransform(tool[4], tool[5])
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, book_pos, book_orn)
        c = int(p.createConstraint(self.robot, self.tool, self.book, -1, pb.JOINT_FIXED, [0, 0, 0], rel_pos,
                                   [0, 0, 0], rel_orn, [0, 0, 0, 1]))
        p.changeConstraint(c, maxForce=300)
        return c

    def close(self) -> None:
        """Disconnects the pybullet client."""
        self.p.disconnect()


def _last_away_from_rest(poses: list[tuple[float, list[tuple[Any, Any]]]]) -> float | None:
    """The last time in ``poses`` (``(t, [(position, quaternion)] per body)``) at which a body is
    farther than ``_REST_M`` or ``_REST_RAD`` from its last pose; ``None`` when none is."""
    if not poses:
        return None
    final = poses[-1][1]
    last = None
    for t, bodies in poses:
        for (pos, orn), (pos_end, orn_end) in zip(bodies, final, strict=True):
            dot = min(1.0, abs(float(np.dot(orn, orn_end))))
            if np.linalg.norm(np.subtract(pos, pos_end)) > _REST_M or 2.0 * math.acos(dot) > _REST_RAD:
                last = t
    return last


def generate_episode(spec: EpisodeSpec, out_dir: Path) -> EpisodeResult:
    """Makes one episode in a fresh pybullet client (textures in a temporary folder)."""
    import time

    start, start_cpu = time.perf_counter(), time.process_time()
    out_dir.mkdir(parents=True, exist_ok=True)
    attempt = 0
    while True:
        drawn = replace(spec, attempt=attempt)
        with tempfile.TemporaryDirectory(prefix="vamos-sim-") as tmp:
            ep = Episode(drawn, Path(tmp))
            try:
                result = ep.run(out_dir)  # plans first: nothing is written for an unreachable draw
            except UnreachableError:
                attempt += 1
                if attempt == _MAX_ATTEMPTS:
                    raise
                continue
            finally:
                ep.close()
        result.seconds = time.perf_counter() - start
        result.cpu_seconds = time.process_time() - start_cpu
        result.attempt = attempt
        return result
