"""The simulated robot: a fixed 6-DoF arm with a two-finger gripper and a pan-tilt head.

The URDF is built from primitives (boxes and cylinders, colours from materials) by
:func:`urdf_text`; the committed copy ``assets/vamos_arm.urdf`` is its output (a test keeps
the two equal). World frame = ``base_link``: x forward (towards the table and the shelf),
z up. The head camera looks forward and down; ``head_camera_optical_frame`` is its optical
frame (z forward, x right, y down), the frame the images are rendered from.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

#: Robot name (also the URDF file stem).
ROBOT_NAME = "vamos_arm"
#: The six arm joints, base to wrist.
ARM_JOINTS = tuple(f"arm_joint_{i}" for i in range(1, 7))
#: The two prismatic finger joints (0 = closed, 0.05 m = open, each).
FINGER_JOINTS = ("finger_left_joint", "finger_right_joint")
#: Pan (about z) and tilt (about y, positive looks down) of the head.
HEAD_JOINTS = ("head_pan_joint", "head_tilt_joint")
#: Every movable joint, in the order of the published joint states.
MOVABLE_JOINTS = ARM_JOINTS + FINGER_JOINTS + HEAD_JOINTS
#: Link whose origin is the grasp point between the fingertips (z along the fingers).
TOOL_LINK = "tool_link"
#: The camera's optical frame.
CAMERA_FRAME = "head_camera_optical_frame"
#: The optical frame of the world-fixed camera (``--camera fixed``).
FIXED_CAMERA_FRAME = "scene_camera_optical_frame"
#: Where the world-fixed camera is (on a bracket above and left of the robot, metres in
#: ``base_link``) and the point it looks at (the shelf's front edge, between table and slot).
FIXED_CAMERA_XYZ = (-0.4, 0.6, 1.45)
FIXED_CAMERA_TARGET = (0.5, 0.0, 0.62)
#: The optical frame of the camera on the arm (``--camera wrist``).
WRIST_CAMERA_FRAME = "wrist_camera_optical_frame"
#: Where the camera on the arm is, metres in the tool link (z along the fingers, fingers
#: closing along y): 6 cm behind the fingers and 12 cm above the grasp point, looking
#: along the fingers, so the fingertips are in the top of the image and the scene below
#: the gripper fills the rest.
WRIST_CAMERA_XYZ = (-0.06, 0.0, -0.12)
#: The cameras an episode can be seen from: the head's (moves with pan and tilt), the
#: world-fixed one, or one on the arm's wrist (moves and turns with the tool).
CAMERAS = ("head", "fixed", "wrist")
#: Position of the head pan joint in ``base_link`` (top of the mast), metres.
HEAD_PAN_XYZ = (-0.6, -0.3, 1.55)
#: Height of the tilt axis above the pan joint, metres.
HEAD_TILT_DZ = 0.10
#: Finger opening per finger, metres.
FINGER_OPEN_M = 0.05
#: Force limit of each finger, newtons: what a finger closed on an object presses with.
FINGER_FORCE_N = 40.0

_COLOURS = {
    "graphite": (0.22, 0.23, 0.26, 1.0),
    "orange": (0.93, 0.45, 0.12, 1.0),
    "steel": (0.62, 0.65, 0.70, 1.0),
    "blue": (0.15, 0.35, 0.75, 1.0),
    "black": (0.08, 0.08, 0.09, 1.0),
}


@dataclass(frozen=True)
class _Visual:
    kind: str  # "box" or "cylinder"
    size: tuple[float, ...]  # box: x y z; cylinder: radius length
    xyz: tuple[float, float, float]
    material: str


def _f(v: float) -> str:
    return f"{v:.12g}"


def _geometry(v: _Visual) -> str:
    if v.kind == "box":
        return f'<box size="{" ".join(_f(s) for s in v.size)}"/>'
    return f'<cylinder radius="{_f(v.size[0])}" length="{_f(v.size[1])}"/>'


def _inertia(mass: float, visuals: list[_Visual]) -> str:
    # A box inertia around the bounding box of the first visual: plausible, not exact.
    v = visuals[0]
    if v.kind == "box":
        x, y, z = v.size
    else:
        x = y = 2 * v.size[0]
        z = v.size[1]
    ixx = mass * (y * y + z * z) / 12
    iyy = mass * (x * x + z * z) / 12
    izz = mass * (x * x + y * y) / 12
    cx, cy, cz = v.xyz
    return (f'    <inertial><origin xyz="{_f(cx)} {_f(cy)} {_f(cz)}"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/></inertial>\n')


def _link(name: str, mass: float, visuals: list[_Visual], collide: bool = True) -> str:
    out = [f'  <link name="{name}">\n']
    if visuals:
        out.append(_inertia(mass, visuals))
    for v in visuals:
        xyz = " ".join(_f(c) for c in v.xyz)
        out.append(f'    <visual><origin xyz="{xyz}" rpy="0 0 0"/><geometry>{_geometry(v)}</geometry>'
                   f'<material name="{v.material}"/></visual>\n')
        if collide:
            out.append(f'    <collision><origin xyz="{xyz}" rpy="0 0 0"/>'
                       f'<geometry>{_geometry(v)}</geometry></collision>\n')
    if not visuals:
        out.append('    <inertial><mass value="0.01"/>'
                   '<inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial>\n')
    out.append("  </link>\n")
    return "".join(out)


def _joint(name: str, kind: str, parent: str, child: str, xyz: tuple[float, float, float],
           rpy: tuple[float, float, float] = (0.0, 0.0, 0.0), axis: tuple[float, float, float] | None = None,
           limits: tuple[float, float, float, float] | None = None) -> str:
    s = [f'  <joint name="{name}" type="{kind}">\n',
         f'    <parent link="{parent}"/><child link="{child}"/>\n',
         f'    <origin xyz="{" ".join(_f(c) for c in xyz)}" rpy="{" ".join(_f(c) for c in rpy)}"/>\n']
    if axis is not None:
        s.append(f'    <axis xyz="{" ".join(_f(c) for c in axis)}"/>\n')
    if limits is not None:
        lo, hi, effort, velocity = limits
        s.append(f'    <limit lower="{_f(lo)}" upper="{_f(hi)}" effort="{_f(effort)}" velocity="{_f(velocity)}"/>\n')
        s.append('    <dynamics damping="0.5" friction="0.0"/>\n')
    s.append("  </joint>\n")
    return "".join(s)


def _header(name: str) -> list[str]:
    parts = [f'<?xml version="1.0"?>\n<robot name="{name}">\n']
    for colour, rgba in _COLOURS.items():
        parts.append(f'  <material name="{colour}"><color rgba="{" ".join(_f(x) for x in rgba)}"/></material>\n')
    return parts


def _base() -> str:
    """Floor plate, pedestal for the arm (top at z = 0.6 m), mast for the head."""
    b, c = "box", "cylinder"
    return _link("base_link", 0.0, [
        _Visual(b, (0.34, 0.34, 0.04), (0.0, 0.0, 0.02), "graphite"),
        _Visual(c, (0.07, 0.56), (0.0, 0.0, 0.32), "steel"),
        _Visual(b, (0.14, 0.14, 0.04), (HEAD_PAN_XYZ[0], HEAD_PAN_XYZ[1], 0.02), "graphite"),
        _Visual(c, (0.03, HEAD_PAN_XYZ[2] - 0.04), (HEAD_PAN_XYZ[0], HEAD_PAN_XYZ[1], HEAD_PAN_XYZ[2] / 2 + 0.02),
                "steel"),
    ])


def _head() -> str:
    """Pan about z on top of the mast, tilt about y (positive looks down), the camera frames."""
    b, c = "box", "cylinder"
    parts = [_joint("head_pan_joint", "revolute", "base_link", "head_pan_link", HEAD_PAN_XYZ,
                    axis=(0, 0, 1), limits=(-1.2, 1.2, 20, 1.5))]
    parts.append(_link("head_pan_link", 0.3, [_Visual(c, (0.045, 0.06), (0.0, 0.0, 0.03), "graphite")]))
    parts.append(_joint("head_tilt_joint", "revolute", "head_pan_link", "head_tilt_link", (0.0, 0.0, HEAD_TILT_DZ),
                        axis=(0, 1, 0), limits=(-0.4, 1.3, 20, 1.5)))
    parts.append(_link("head_tilt_link", 0.4, [_Visual(b, (0.09, 0.18, 0.07), (-0.01, 0.0, 0.0), "graphite")]))
    parts.append(_joint("head_camera_joint", "fixed", "head_tilt_link", "head_camera_link", (0.05, 0.0, 0.0)))
    parts.append(_link("head_camera_link", 0.0, []))
    parts.append(_joint("head_camera_optical_joint", "fixed", "head_camera_link", CAMERA_FRAME, (0.0, 0.0, 0.0),
                        rpy=(-math.pi / 2, 0.0, -math.pi / 2)))
    parts.append(_link(CAMERA_FRAME, 0.0, []))
    return "".join(parts)


def camera_frame(camera: str) -> str:
    """The optical frame images are rendered from, for a camera of :data:`CAMERAS`."""
    return {"fixed": FIXED_CAMERA_FRAME, "wrist": WRIST_CAMERA_FRAME}.get(camera, CAMERA_FRAME)


def _wrist_camera(tool_link: str) -> str:
    """A camera fixed to the tool link at :data:`WRIST_CAMERA_XYZ`, its optical frame
    looking along the fingers (optical z = tool z, optical x = tool y)."""
    parts = [_joint("wrist_camera_joint", "fixed", tool_link, WRIST_CAMERA_FRAME, WRIST_CAMERA_XYZ,
                    rpy=(0.0, 0.0, math.pi / 2))]
    parts.append(_link(WRIST_CAMERA_FRAME, 0.0, []))
    return "".join(parts)


def _extra_camera(camera: str, tool_link: str) -> str:
    """The links of a camera that is not the head's: world-fixed or on the wrist."""
    if camera == "fixed":
        return _fixed_camera()
    if camera == "wrist":
        return _wrist_camera(tool_link)
    return ""


def _fixed_camera() -> str:
    """A camera mount fixed to ``base_link`` (the world: the robot's base does not move),
    its body frame (x forward, z up) looking from :data:`FIXED_CAMERA_XYZ` at
    :data:`FIXED_CAMERA_TARGET`, and its optical frame."""
    d = [t - p for t, p in zip(FIXED_CAMERA_TARGET, FIXED_CAMERA_XYZ, strict=True)]
    yaw = math.atan2(d[1], d[0])
    pitch = math.atan2(-d[2], math.hypot(d[0], d[1]))
    parts = [_joint("scene_camera_joint", "fixed", "base_link", "scene_camera_link", FIXED_CAMERA_XYZ,
                    rpy=(0.0, pitch, yaw))]
    parts.append(_link("scene_camera_link", 0.0, []))
    parts.append(_joint("scene_camera_optical_joint", "fixed", "scene_camera_link", FIXED_CAMERA_FRAME,
                        (0.0, 0.0, 0.0), rpy=(-math.pi / 2, 0.0, -math.pi / 2)))
    parts.append(_link(FIXED_CAMERA_FRAME, 0.0, []))
    return "".join(parts)


def urdf_text(camera: str = "head") -> str:
    """The robot's URDF (deterministic text); with ``camera="fixed"`` or ``"wrist"`` it also
    describes that camera (the head stays: it moves as in every episode)."""
    b, c = "box", "cylinder"
    parts = _header(ROBOT_NAME)
    parts.append(_base())
    arm = [
        # (link, mass, visuals, joint origin in parent, axis, limits)
        ("arm_link_1", 3.0, [_Visual(c, (0.075, 0.12), (0.0, 0.0, 0.06), "orange")],
         (0.0, 0.0, 0.60), (0, 0, 1), (-2.9, 2.9, 150, 2.0)),
        ("arm_link_2", 2.5, [_Visual(b, (0.08, 0.09, 0.45), (0.0, 0.0, 0.225), "orange"),
                             _Visual(c, (0.055, 0.10), (0.0, 0.0, 0.0), "graphite")],
         (0.0, 0.0, 0.12), (0, 1, 0), (-2.0, 2.0, 150, 2.0)),
        ("arm_link_3", 1.8, [_Visual(b, (0.065, 0.07, 0.40), (0.0, 0.0, 0.20), "orange"),
                             _Visual(c, (0.045, 0.09), (0.0, 0.0, 0.0), "graphite")],
         (0.0, 0.0, 0.45), (0, 1, 0), (-2.6, 2.6, 100, 2.0)),
        ("arm_link_4", 0.6, [_Visual(c, (0.035, 0.08), (0.0, 0.0, 0.04), "steel")],
         (0.0, 0.0, 0.40), (0, 0, 1), (-3.0, 3.0, 80, 3.0)),
        ("arm_link_5", 0.5, [_Visual(b, (0.06, 0.06, 0.08), (0.0, 0.0, 0.04), "blue")],
         (0.0, 0.0, 0.08), (0, 1, 0), (-2.2, 2.2, 80, 3.0)),
        ("arm_link_6", 0.3, [_Visual(c, (0.04, 0.03), (0.0, 0.0, 0.015), "steel")],
         (0.0, 0.0, 0.09), (0, 0, 1), (-3.0, 3.0, 40, 3.0)),
    ]
    parent = "base_link"
    for i, (link, mass, visuals, xyz, axis, limits) in enumerate(arm):
        parts.append(_joint(ARM_JOINTS[i], "revolute", parent, link, xyz, axis=axis, limits=limits))
        parts.append(_link(link, mass, visuals))
        parent = link
    parts.append(_joint("gripper_joint", "fixed", parent, "gripper_base", (0.0, 0.0, 0.03)))
    parts.append(_link("gripper_base", 0.4, [_Visual(b, (0.05, 0.15, 0.04), (0.0, 0.0, 0.02), "graphite")]))
    for name, sign in (("left", 1.0), ("right", -1.0)):
        parts.append(_joint(f"finger_{name}_joint", "prismatic", "gripper_base", f"finger_{name}_link",
                            (0.0, 0.0, 0.04), axis=(0, sign, 0), limits=(0.0, FINGER_OPEN_M, FINGER_FORCE_N, 0.2)))
        parts.append(_link(f"finger_{name}_link", 0.05,
                           [_Visual(b, (0.02, 0.015, 0.075), (0.0, sign * 0.0075, 0.0375), "black")]))
    parts.append(_joint("tool_joint", "fixed", "gripper_base", TOOL_LINK, (0.0, 0.0, 0.085)))
    parts.append(_link(TOOL_LINK, 0.0, []))
    parts.append(_head())
    parts.append(_extra_camera(camera, TOOL_LINK))
    parts.append("</robot>\n")
    return "".join(parts)


def _panda_source() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / "franka_panda"


def panda_urdf_text(camera: str = "head") -> str:
    """The franka_panda arm of pybullet_data (meshes, ``package://meshes/...``) on the same
    pedestal, with the same pan-tilt head and camera (and the world-fixed one, as
    :func:`urdf_text`)."""
    text = (_panda_source() / "panda.urdf").read_text()
    body = text[text.index(">", text.index("<robot")) + 1:text.rindex("</robot>")]
    parts = _header(PANDA_NAME)
    parts.append(_base())
    parts.append(_joint("panda_mount_joint", "fixed", "base_link", "panda_link0", (0.0, 0.0, 0.6)))
    parts.append(body)
    parts.append(_head())
    parts.append(_extra_camera(camera, "panda_grasptarget"))
    parts.append("</robot>\n")
    return "".join(parts)


@dataclass(frozen=True)
class RobotModel:
    """What the simulation needs to know about a robot."""

    #: URDF robot name and file stem.
    name: str
    #: Arm joints, base to wrist.
    arm_joints: tuple[str, ...]
    #: Prismatic finger joints (0 = closed).
    finger_joints: tuple[str, str]
    #: Grasp-point link (z along the fingers, fingers closing along y).
    tool_link: str
    #: Links the held book never collides with.
    gripper_links: tuple[str, ...]
    #: Finger opening per finger, metres.
    finger_open_m: float
    #: Arm posture at rest (tool above the workspace, pointing down).
    home: tuple[float, ...]

    @property
    def movable_joints(self) -> tuple[str, ...]:
        """Every movable joint, in the order of the published joint states (the URDF order)."""
        return self.arm_joints + self.finger_joints + HEAD_JOINTS

    def urdf_text(self, camera: str = "head") -> str:
        """The URDF text (with the world-fixed or wrist camera's links for ``camera="fixed"``
        or ``"wrist"``)."""
        return panda_urdf_text(camera) if self.name == PANDA_NAME else urdf_text(camera)

    def write_package(self, folder: Path, camera: str = "head") -> Path:
        """Writes the robot package folder (URDF, and meshes + licence for the panda);
        returns the URDF path."""
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{self.name}.urdf"
        path.write_text(self.urdf_text(camera))
        if self.name == PANDA_NAME:
            src = _panda_source()
            shutil.copytree(src / "meshes", folder / "meshes", dirs_exist_ok=True)
            shutil.copy(src / "LICENSE.txt", folder / "LICENSE.panda-meshes.txt")
        return path


#: Name of the franka_panda variant.
PANDA_NAME = "vamos_panda"
#: The primitive robot (default).
VAMOS_ARM = RobotModel(ROBOT_NAME, ARM_JOINTS, FINGER_JOINTS, TOOL_LINK,
                       ("gripper_base", "finger_left_link", "finger_right_link", "arm_link_6"), FINGER_OPEN_M,
                       (0.0, 0.25, 1.75, 0.0, 1.1, 0.0))
#: The franka_panda arm from pybullet_data (meshes), 7 DoF.
PANDA = RobotModel(PANDA_NAME, tuple(f"panda_joint{i}" for i in range(1, 8)),
                   ("panda_finger_joint1", "panda_finger_joint2"), "panda_grasptarget",
                   ("panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_link7", "panda_link8"), 0.04,
                   (0.0, -0.2, 0.0, -2.3, 0.0, 2.1, 0.785))
#: Robots by the name ``--robot`` takes.
ROBOTS = {"primitive": VAMOS_ARM, "panda": PANDA}


def asset_path() -> Path:
    """The packaged URDF file (``vamos/sim/assets/vamos_arm.urdf``)."""
    return Path(str(resources.files("vamos.sim") / "assets" / f"{ROBOT_NAME}.urdf"))
