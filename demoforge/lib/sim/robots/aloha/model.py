"""MJCF of two ViperX 300 6-DOF arms (the ALOHA puppet arms) derived from gym-aloha 0.1.5's model.

`arm_xml(side, base, hand, spec)` builds one arm from `assets/vx300s_left.xml` (kept verbatim; see
assets/README.md). What is changed, and why:

* names: `vx300s_left/<part>` becomes `<side>_<part>` (side `left` or `right`), the base body `<side>_base`,
  placed at the task's `BasePose` (lib/sim/robots/aloha/placement.py) instead of gym-aloha's table;
* the wrist camera, its focus body and the calibration sites are dropped (the scene has its own camera);
* collisions: every link geom touches objects, the table and the other arm (contype = conaffinity = 3,
  as the grippers' geoms); the links of one arm never collide with each other (a real ViperX's joint
  ranges keep them apart; the model's convex hulls of neighbouring links overlap);
* drive: gym-aloha holds its arms with large joint friction (30-60 N m) and weak position gains; here
  each of the 6 joints has a position actuator with damping (kv), a torque limit of its Dynamixel
  servos (XM540-W270: 10.6 N m, doubled on the shoulder and elbow; XM430-W350 on the wrist rotate:
  4.1 N m), gravity compensation (like the arm's controller would) and the armature of its gearbox;
* hand `aloha`: ALOHA's own fingers (the custom finger meshes, 69 mm between the pads fully open) on
  slide joints re-expressed as demoforge's finger drive (lib/sim/gripper.py finger_drive: coupled,
  one force-limited actuator, travel 0 = open), with the project's pad friction and contact stiffness;
* hand `2f140`: the ViperX gripper's bar, prop and fingers are replaced by the 2F-140 the floating
  grippers use (lib/sim/gripper.py), its palm mounted on the wrist servo (the wrist-rotate link);
* a body `<side>_hand` on the wrist-rotate link carries the pinch site `<side>_hand_pinch` in the
  gripper frame of docs/architecture.md (z = approach = the link's x, x = closing = the link's y), at
  the pinch point between the fingertips (12 mm behind the ALOHA fingertips' ends, 6 mm behind the
  2F-140's).
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from demoforge.lib.geometry import matrix_to_quat, xyzw_to_wxyz
from demoforge.lib.sim.gripper import BITS, COLORS, PAD_SOL, GripperSpec, finger_drive, hand_body
from demoforge.lib.sim.gripper import mjcf_numbers as _f

ASSETS = Path(__file__).resolve().parent / "assets"
ARM_FILE = "vx300s_left.xml"
MESH_FILE = "vx300s_dependencies.xml"
SIDES = ("left", "right")
JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
# per joint: position gain (N m / rad), damping gain (N m s / rad), torque limit (N m), armature (kg m^2),
# speed limit for the IK (rad/s: the servos' no-load speed at 12 V, XM540-W270 30 rpm, XM430-W350 46 rpm)
KP = (400.0, 800.0, 600.0, 150.0, 150.0, 60.0)
KV = (40.0, 80.0, 50.0, 8.0, 8.0, 3.0)
TORQUE = (10.6, 21.2, 21.2, 10.6, 10.6, 4.1)
ARMATURE = (0.05, 0.1, 0.08, 0.02, 0.02, 0.01)
SPEED = (3.14, 3.14, 3.14, 3.14, 3.14, 4.8)
# the joint angles gym-aloha starts its arms in (START_ARM_POSE): folded, the gripper in front of the base
REST = (0.0, -0.96, 1.16, 0.0, -0.3, 0.0)
# where the pinch site sits on the wrist-rotate link (x along the approach), per hand
ALOHA_TIP_X = 0.1537  # the finger meshes' far end, link x, m (measured on the meshes)
PINCH_X = {"aloha": ALOHA_TIP_X - 0.012}
SERVO_FRONT_X = 0.0428  # front face of the wrist servo housing (vx300s_7_gripper), link x, m
# link frame -> gripper frame: gripper x = link y, y = link z, z = link x
LINK_TO_GRIPPER = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

ALOHA_HAND = GripperSpec(name="aloha_vx300s", stroke=0.069, open_width=None, finger_mass=0.035,
                         tip_offset=0.012, finger_len=0.09)


def hand_spec(hand: str) -> GripperSpec:
    if hand == "aloha":
        return ALOHA_HAND
    if hand == "2f140":
        return GripperSpec()
    raise ValueError(f"unknown hand {hand!r}: aloha or 2f140")


def pinch_x(hand: str, spec: GripperSpec) -> float:
    """Link x of the pinch point: for the 2F-140, its palm's back face against the wrist servo."""
    if hand == "aloha":
        return PINCH_X["aloha"]
    return SERVO_FRONT_X + 2 * spec.palm_half[2] + spec.finger_len - spec.tip_offset


@dataclass(frozen=True)
class BasePose:
    """Where an arm's base stands: position (m, world) and yaw about z (rad; 0 = the arm reaches along +x)."""
    x: float
    y: float
    z: float
    yaw: float

    def mirrored(self) -> "BasePose":
        """The other arm's base: reflected across x = 0 (the world's mirror plane)."""
        return BasePose(-self.x, self.y, self.z, math.pi - self.yaw)

    def matrix(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        T = np.eye(4)
        T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        T[:3, 3] = (self.x, self.y, self.z)
        return T


def _quat_wxyz(R: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in xyzw_to_wxyz(matrix_to_quat(R)))


@functools.lru_cache(maxsize=None)
def _template() -> str:
    return (ASSETS / ARM_FILE).read_text()


@functools.lru_cache(maxsize=1)
def mesh_assets() -> tuple[str, dict[str, bytes]]:
    """(`<mesh>` elements, {file name: bytes}) of the meshes the arm names."""
    root = ET.fromstring((ASSETS / MESH_FILE).read_text())
    meshes = root.find("asset").findall("mesh")
    files = {m.get("file"): (ASSETS / m.get("file")).read_bytes() for m in meshes}
    return "\n".join(ET.tostring(m, encoding="unicode").strip() for m in meshes), files


def _rename(el: ET.Element, side: str) -> None:
    for node in el.iter():
        name = node.get("name")
        if name == "vx300s_left":
            node.set("name", f"{side}_base")
        elif name and name.startswith("vx300s_left/"):
            node.set("name", f"{side}_{name.split('/', 1)[1]}")


def _drop(parent: ET.Element, pred) -> None:
    for node in list(parent.iter()):
        for child in list(node):
            if pred(child):
                node.remove(child)


def arm_xml(side: str, base: BasePose, hand: str, spec: GripperSpec, fingers: bool = True) -> str:
    """One arm's `<body>` tree (see the module docstring). `fingers=False`: the kinematic tree only (no
    finger joints; the inverse kinematics' model)."""
    root = ET.fromstring(_template())
    arm = root.find("body")
    _rename(arm, side)
    _drop(arm, lambda c: c.tag in ("camera", "site") or c.get("name") == f"{side}_camera_focus")
    arm.set("pos", _f(base.x, base.y, base.z))
    arm.set("quat", _f(*_quat_wxyz(base.matrix()[:3, :3])))
    for j, name in enumerate(JOINTS):
        joint = arm.find(f".//joint[@name='{side}_{name}']")
        joint.attrib.pop("frictionloss", None)
        joint.set("armature", _f(ARMATURE[j]))
        joint.set("damping", "0.1")
    for body in arm.iter("body"):
        if body is not arm:
            body.set("gravcomp", "1")
    for geom in arm.iter("geom"):
        if geom.get("name") != f"{side}_1_base":
            geom.set("contype", "3")
            geom.set("conaffinity", "3")
            geom.set("group", "1")
    link = arm.find(f".//body[@name='{side}_gripper_link']")
    finger_bodies = [b for b in link.findall("body") if b.get("name", "").endswith("finger_link")]
    for b in finger_bodies:
        link.remove(b)
    if hand == "2f140":
        _drop(link, lambda c: c.get("name") in (f"{side}_9_gripper_bar", f"{side}_gripper_prop_link"))
    px = pinch_x(hand, spec)
    hand_el = ET.SubElement(link, "body", name=f"{side}_hand", pos=_f(px, 0, 0),
                            quat=_f(*_quat_wxyz(LINK_TO_GRIPPER)), gravcomp="1")
    text = ET.tostring(arm, encoding="unicode")
    inside = ""
    if hand == "2f140":
        inside = hand_body(spec, f"{side}_hand", COLORS[SIDES.index(side)], wrist=False) if fingers else \
            f'<site name="{side}_hand_pinch" pos="0 0 0" size="0.004" group="3"/>'
    else:
        inside = f'<site name="{side}_hand_pinch" pos="0 0 0" size="0.004" rgba="1 1 0 1" group="3"/>'
        if fingers:
            inside += _aloha_fingers(side, spec, px)
    marker = ET.tostring(hand_el, encoding="unicode")
    return text.replace(marker, marker.replace("/>", f">{inside}</body>", 1), 1)


def _aloha_fingers(side: str, spec: GripperSpec, px: float) -> str:
    """ALOHA's two fingers inside the hand body (gripper frame), each in a body whose axes are the wrist
    link's again (so the meshes keep gym-aloha's placement): open = gym-aloha's joint value 0.057."""
    p = f"{side}_hand"
    back = _f(*_quat_wxyz(LINK_TO_GRIPPER.T))
    fr = _f(*spec.pad_friction)
    half = spec.stroke / 2
    out = []
    # demoforge's left finger (-x of the gripper frame) is gym-aloha's right finger (-y of the link)
    for ours, theirs, sgn in (("l", "right", -1), ("r", "left", 1)):
        mesh = f"vx300s_10_gripper_finger_{theirs}"
        out.append(f"""
<body name="{p}_finger_{ours}" pos="{_f(sgn * 0.057, 0, 0.0687 - px)}" quat="{back}" gravcomp="1">
  <inertial pos="0.017344 {-sgn * 0.0060692:.7g} 0" quat="0.449364 {sgn * 0.449364:.6g} {-sgn * 0.54596:.6g} -0.54596" mass="{spec.finger_mass:.6g}" diaginertia="2.48003e-05 1.417e-05 1.20797e-05"/>
  <joint name="{p}_{ours}" type="slide" axis="{_f(0, -sgn, 0)}" range="0 {half:.6g}" armature="0.01" damping="0.5" solreflimit="0.004 1"/>
  <geom name="{p}_pad_{ours}" type="mesh" mesh="{mesh}" pos="0.005 {-sgn * 0.052:.6g} 0" euler="3.14 1.57 0" {BITS} {PAD_SOL}
        friction="{fr}" condim="4" group="1" rgba="0.15 0.15 0.15 1"/>
</body>""")
    return "".join(out)


def arms_parts(bases: tuple[BasePose, BasePose], hand: str, spec: GripperSpec) -> dict[str, str]:
    """Both arms: worldbody, equality, tendon, actuator and contact fragments."""
    wb, eq, tn, ac, ct = [], [], [], [], []
    for side, base in zip(SIDES, bases):
        if base.z > 0:  # a base raised above the table top stands on a riser (drawn; the arm never reaches under it)
            wb.append(f'<geom name="{side}_riser" type="box" pos="{_f(base.x, base.y, base.z / 2)}" '
                      f'size="{_f(0.07, 0.07, base.z / 2)}" rgba="0.2 0.2 0.22 1" contype="0" conaffinity="0"/>')
        wb.append(arm_xml(side, base, hand, spec))
        drive = finger_drive(spec, f"{side}_hand")
        eq.append(drive["equality"])
        tn.append(drive["tendon"])
        for j, name in enumerate(JOINTS):
            lo, hi = _joint_range(name)
            # commands may lead the joint's range by the velocity feed-forward (aloha/__init__.py): the
            # joint's own limit stops it
            ac.append(f'<position name="{side}_{name}" joint="{side}_{name}" kp="{KP[j]:.6g}" kv="{KV[j]:.6g}" '
                      f'forcerange="{_f(-TORQUE[j], TORQUE[j])}" ctrlrange="{_f(lo - 0.5, hi + 0.5)}"/>')
        ac.append(drive["actuator"])
        bodies = arm_bodies(wb[-1])  # the arm just added
        ct += [f'<exclude body1="{a}" body2="{b}"/>' for i, a in enumerate(bodies) for b in bodies[i + 1:]]
    return {"worldbody": "\n".join(wb), "equality": "\n".join(eq), "tendon": "\n".join(tn),
            "actuator": "\n".join(ac), "contact": "\n".join(ct)}


def arm_bodies(xml: str) -> list[str]:
    """The names of the bodies of one arm's `<body>` tree (its base first)."""
    return [b.get("name") for b in ET.fromstring(xml).iter("body")]


@functools.lru_cache(maxsize=None)
def _joint_range(name: str) -> tuple[float, float]:
    joint = ET.fromstring(_template()).find(f".//joint[@name='vx300s_left/{name}']")
    lo, hi = (float(v) for v in joint.get("range").split())
    return lo, hi


def kinematic_model_xml(bases: tuple[BasePose, BasePose], hand: str, spec: GripperSpec) -> tuple[str, dict]:
    """(MJCF, assets) of the two arms and the table top, without finger joints: the inverse kinematics' model
    (its 12 joints in the order left then right, JOINTS within each; sites `<side>_hand_pinch`; the table for
    mink's collision limits, the same box as the task scenes')."""
    mesh_xml, files = mesh_assets()
    arms = "\n".join(arm_xml(side, base, hand, spec, fingers=False) for side, base in zip(SIDES, bases))
    xml = f"""<mujoco model="aloha_ik">
<compiler angle="radian" autolimits="true"/>
<asset>
{mesh_xml}
</asset>
<worldbody>
<geom name="table_top" type="box" pos="0 0.3 -0.02" size="0.75 0.45 0.02" contype="2" conaffinity="2"/>
{arms}
</worldbody>
</mujoco>"""
    return xml, files
