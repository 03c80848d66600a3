"""Primitive-built MJCF objects (boxes, cylinders, capsules, spheres) for the six tasks.

Every object is built in its own frame: origin at the centre of its support footprint (bottom), z up,
and its geometry is mirror-symmetric in local x (x -> -x), so that reflecting a scene across the
world plane x = 0 maps every object onto itself with pose M T M (M = diag(-1, 1, 1)).
Masses are distributed over the geoms in proportion to their volume.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

FRICTION = "1.2 0.02 0.002"  # sliding friction high enough for a pinch grasp
# Collision bits: table and floor use contype = conaffinity = 2 (TABLE_BITS); solid object geoms (bottoms,
# handles, balls, ...) use 3, so they touch the table and every default (1/1) geom; thin container walls
# keep MuJoCo's default 1/1: they touch all objects (and a robot's default geoms) but not the table,
# which saves about a hundred resting box-box contacts per scene.
SOLID_BITS = 3
TABLE_BITS = 2


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.ravel(v))


def quat_wxyz(rot: Rotation) -> np.ndarray:
    q = rot.as_quat()
    return np.array([q[3], q[0], q[1], q[2]])


class GeomSet:
    """Collects the geoms of one body; `xml(total_mass)` spreads the mass by volume."""

    def __init__(self, name: str, rgba: str, friction: str = FRICTION, extra: str = ""):
        self.name = name
        self.rgba = rgba
        self.friction = friction
        self.extra = extra
        self._geoms: list[tuple[str, float]] = []

    def _add(self, attrs: str, volume: float, rgba: str | None, wall: bool = False) -> None:
        bits = "" if wall else f' contype="{SOLID_BITS}" conaffinity="{SOLID_BITS}"'
        self._geoms.append((f'{attrs} rgba="{rgba or self.rgba}"{bits}', volume))

    def box(self, pos, half, rot: Rotation | None = None, rgba: str | None = None, wall: bool = False):
        q = "" if rot is None else f' quat="{_fmt(quat_wxyz(rot))}"'
        self._add(f'type="box" pos="{_fmt(pos)}" size="{_fmt(half)}"{q}', 8 * np.prod(half), rgba, wall)

    def cylinder(self, pos, radius, half_height, rgba: str | None = None):
        self._add(f'type="cylinder" pos="{_fmt(pos)}" size="{radius:.6g} {half_height:.6g}"',
                  math.pi * radius**2 * 2 * half_height, rgba)

    def capsule(self, p0, p1, radius, rgba: str | None = None):
        length = float(np.linalg.norm(np.subtract(p1, p0)))
        self._add(f'type="capsule" fromto="{_fmt(p0)} {_fmt(p1)}" size="{radius:.6g}"',
                  math.pi * radius**2 * length + 4 / 3 * math.pi * radius**3, rgba)

    def sphere(self, pos, radius, rgba: str | None = None):
        self._add(f'type="sphere" pos="{_fmt(pos)}" size="{radius:.6g}"', 4 / 3 * math.pi * radius**3, rgba)

    def ring(self, n: int, r_in: float, t: float, z0: float, z1: float, rgba: str | None = None):
        """Vertical tube wall from n thin boxes, inner radius r_in, thickness t."""
        half_tan = (r_in + t) * math.tan(math.pi / n) * 1.05
        for i in range(n):
            th = 2 * math.pi * i / n
            rc = r_in + t / 2
            self.box([rc * math.cos(th), rc * math.sin(th), (z0 + z1) / 2], [t / 2, half_tan, (z1 - z0) / 2],
                     Rotation.from_euler("z", th), rgba, wall=True)

    def cone_ring(self, n: int, r0: float, z0: float, r1: float, z1: float, t: float, rgba: str | None = None):
        """Conical wall from n boxes whose inner faces run from (r0, z0) to (r1, z1)."""
        dr, dz = r1 - r0, z1 - z0
        length = math.hypot(dr, dz)
        beta = math.atan2(dr, dz)
        half_tan = (max(r0, r1) + t) * math.tan(math.pi / n) * 1.08
        normal = np.array([math.cos(beta), -math.sin(beta)])  # outward in the (r, z) plane
        mid = np.array([(r0 + r1) / 2, (z0 + z1) / 2]) + normal * t / 2
        for i in range(n):
            th = 2 * math.pi * i / n
            rot = Rotation.from_euler("z", th) * Rotation.from_euler("y", beta)
            self.box([mid[0] * math.cos(th), mid[0] * math.sin(th), mid[1]], [t / 2, half_tan, length / 2], rot, rgba,
                     wall=True)

    def xml(self, total_mass: float) -> str:
        vol = sum(v for _, v in self._geoms)
        out = []
        for i, (g, v) in enumerate(self._geoms):
            out.append(f'<geom name="{self.name}_g{i}" {g} mass="{total_mass * v / vol:.6g}" '
                       f'friction="{self.friction}" {self.extra}/>')
        return "\n".join(out)


def body_xml(name: str, pose: np.ndarray, geoms: str) -> str:
    q = quat_wxyz(Rotation.from_matrix(pose[:3, :3]))
    return (f'<body name="{name}" pos="{_fmt(pose[:3, 3])}" quat="{_fmt(q)}">\n'
            f'<freejoint name="{name}_joint"/>\n{geoms}\n</body>')


# ------------------------------------------------------------------ object geometry
# Dimensions (metres) are module constants so that tasks and predicates share them.

BOTTLE = dict(R=0.035, t=0.004, body_h=0.15, shoulder_h=0.035, neck_r=0.0135, neck_t=0.003, h=0.23, mass=0.20,
              side_z=0.08)
CUP = dict(R=0.045, t=0.004, h=0.10, mass=0.12)
LIQUID = dict(n=10, r=0.0065, mass=0.004)
CAN = dict(R=0.033, h=0.12, mass=0.06)
BIN = dict(half=0.10, t=0.006, h=0.18, mass=0.40)
BALL = dict(r=0.03, mass=0.012)
CASE = dict(hx=0.11, hy=0.065, t=0.006, h=0.06, lid_angle=math.radians(105), mass=0.25)
BOWL = dict(r_bot=0.055, r_top=0.095, h=0.075, t=0.005, mass=0.30, center_z=0.04)
WHISK = dict(handle_r=0.006, handle_len=0.13, head_r=0.025, head_z=0.17, mass=0.08, grasp_z=0.075)
CONTAINER = dict(hx=0.07, hy=0.05, t=0.005, h=0.08, mass=0.20)
LID = dict(hx=0.076, hy=0.056, t=0.006, skirt=0.015, skirt_t=0.003, knob=(0.02, 0.006, 0.008), mass=0.06)
VASE = dict(R=0.045, t=0.004, h=0.20, mass=0.50)
FLOWERS = dict(base=0.015, base_h=0.012, top=0.30, side=0.025, side_top=0.28, blossom_r=0.02, stem_r=0.003, mass=0.05)

# How each dimension of the resizable objects follows a resize (Task.variant / demoforge.lib.sim.variations): "r" scales
# with the horizontal factor (radii, half-widths), "z" with the vertical one (heights), "m" with the
# volume (mass), "t" stays (wall and neck thickness: a bigger cup of the same kind has the same walls).
# Extra keys: side_z, center_z, grasp_z are the heights of a keypoint / grasp point on the object.
DIM_KINDS = {
    "bottle": dict(R="r", t="t", body_h="z", shoulder_h="z", neck_r="r", neck_t="t", h="z", mass="m", side_z="z"),
    "cup": dict(R="r", t="t", h="z", mass="m"),
    "can": dict(R="r", h="z", mass="m"),
    "bin": dict(half="r", t="t", h="z", mass="m"),
    "bowl": dict(r_bot="r", r_top="r", h="z", t="t", mass="m", center_z="z"),
    "whisk": dict(handle_r="r", handle_len="z", head_r="r", head_z="z", mass="m", grasp_z="z"),
}


def scale_dims(obj: str, dims: dict, s_xy: float, s_z: float) -> dict:
    """`dims` of object `obj` resized by s_xy horizontally and s_z vertically (see DIM_KINDS)."""
    kinds = DIM_KINDS.get(obj)
    if kinds is None:
        raise ValueError(f"object {obj!r} cannot be resized; resizable: {', '.join(DIM_KINDS)}")
    if not (s_xy > 0 and s_z > 0):
        raise ValueError(f"scale factors must be positive, got s_xy={s_xy}, s_z={s_z}")
    factor = {"r": s_xy, "z": s_z, "m": s_xy * s_xy * s_z, "t": 1.0}
    missing = set(dims) - set(kinds)
    if missing:
        raise ValueError(f"{obj}: no resize rule for dimension(s) {sorted(missing)}; add them to DIM_KINDS")
    return {k: float(v) * factor[kinds[k]] for k, v in dims.items()}


def bottle(pose, dims: dict | None = None):
    g = GeomSet("bottle", "0.2 0.6 0.3 0.85")
    b = dims or BOTTLE
    g.cylinder([0, 0, 0.004], b["R"] - 0.001, 0.004)
    g.ring(16, b["R"] - b["t"], b["t"], 0.0, b["body_h"])
    g.cone_ring(16, b["R"] - b["t"], b["body_h"], b["neck_r"], b["body_h"] + b["shoulder_h"], b["t"])
    g.ring(10, b["neck_r"], b["neck_t"], b["body_h"] + b["shoulder_h"] - 0.002, b["h"])
    return body_xml("bottle", pose, g.xml(b["mass"]))


#: Geom group of simulation-only geoms (the liquid): the kinematic renders of a take do not simulate
#: them, so the renderer hides this group instead of drawing spheres where the scene file put them.
SIM_ONLY_GROUP = 3


def liquid(bottle_pose, dims: dict | None = None):
    """Small spheres stacked inside the bottle (layers of 4); `dims`: the bottle's (default BOTTLE)."""
    out = []
    b, lq = dims or BOTTLE, LIQUID
    # ring radius of the spheres: 14 mm in the default bottle, less in a narrower one (stay inside its wall)
    ring = min(0.014, b["R"] - b["t"] - lq["r"] - 0.001)
    for i in range(lq["n"]):
        layer, k = divmod(i, 4)
        ang = math.pi / 4 + math.pi / 2 * k + layer * 0.4
        p_local = np.array([ring * math.cos(ang), ring * math.sin(ang), 0.008 + lq["r"] + 0.001 + layer * 0.0145])
        pose = np.eye(4)
        pose[:3, 3] = bottle_pose[:3, :3] @ p_local + bottle_pose[:3, 3]
        g = GeomSet(f"liquid_{i}", "0.2 0.4 1 1", friction="0.3 0.005 0.0001", extra=f'group="{SIM_ONLY_GROUP}"')
        g.sphere([0, 0, 0], lq["r"])
        out.append(body_xml(f"liquid_{i}", pose, g.xml(lq["mass"])))
    return "\n".join(out)


def cup(pose, dims: dict | None = None):
    g = GeomSet("cup", "0.9 0.9 0.95 1")
    c = dims or CUP
    g.cylinder([0, 0, 0.005], c["R"] - 0.001, 0.005)
    g.ring(16, c["R"] - c["t"], c["t"], 0.0, c["h"])
    return body_xml("cup", pose, g.xml(c["mass"]))


def can(pose, dims: dict | None = None):
    g = GeomSet("can", "0.8 0.1 0.1 1")
    c = dims or CAN
    g.cylinder([0, 0, c["h"] / 2], c["R"], c["h"] / 2)
    return body_xml("can", pose, g.xml(c["mass"]))


def bin_(pose, dims: dict | None = None):
    g = GeomSet("bin", "0.3 0.3 0.35 1")
    b = dims or BIN
    a, t, h = b["half"], b["t"], b["h"]
    g.box([0, 0, t / 2], [a, a, t / 2])
    for sx, sy in ((1, 0), (-1, 0)):
        g.box([sx * (a - t / 2), 0, h / 2], [t / 2, a, h / 2], wall=True)
    for sy in (1, -1):
        g.box([0, sy * (a - t / 2), h / 2], [a - t, t / 2, h / 2], wall=True)
    return body_xml("bin", pose, g.xml(b["mass"]))


def paper_ball(pose):
    g = GeomSet("paper_ball", "0.95 0.95 0.85 1", friction="1.0 0.05 0.01", extra='condim="6"')
    g.sphere([0, 0, BALL["r"]], BALL["r"])
    return body_xml("paper_ball", pose, g.xml(BALL["mass"]))


def _open_box(g, hx, hy, t, h):
    """A bottom plate and four thin walls: an open box of half-extents hx, hy, wall t, height h."""
    g.box([0, 0, t / 2], [hx, hy, t / 2])
    for sx in (1, -1):
        g.box([sx * (hx - t / 2), 0, h / 2], [t / 2, hy, h / 2], wall=True)
    for sy in (1, -1):
        g.box([0, sy * (hy - t / 2), h / 2], [hx - t, t / 2, h / 2], wall=True)


def case(pose):
    g = GeomSet("case", "0.15 0.2 0.6 1")
    c = CASE
    hx, hy, t, h = c["hx"], c["hy"], c["t"], c["h"]
    _open_box(g, hx, hy, t, h)
    # open lid hinged at the back top edge, leaning back by lid_angle from the closed position
    ang = c["lid_angle"]
    d = np.array([0.0, math.cos(math.pi - ang), math.sin(math.pi - ang)])  # direction away from the hinge
    hinge = np.array([0.0, hy, h])
    g.box(hinge + d * hy, [hx, t / 2, hy], Rotation.from_euler("x", -(math.pi / 2 - (math.pi - ang))),
          rgba="0.2 0.25 0.7 1", wall=True)
    return body_xml("case", pose, g.xml(c["mass"]))


def case_lid_tip_local() -> np.ndarray:
    c = CASE
    ang = c["lid_angle"]
    d = np.array([0.0, math.cos(math.pi - ang), math.sin(math.pi - ang)])
    return np.array([0.0, c["hy"], c["h"]]) + d * 2 * c["hy"]


def bowl(pose, dims: dict | None = None):
    g = GeomSet("bowl", "0.95 0.6 0.2 1")
    b = dims or BOWL
    g.cylinder([0, 0, 0.003], b["r_bot"] + 0.002, 0.003)
    g.cone_ring(20, b["r_bot"], 0.0, b["r_top"], b["h"], b["t"])
    return body_xml("bowl", pose, g.xml(b["mass"]))


def whisk(pose, dims: dict | None = None):
    g = GeomSet("whisk", "0.75 0.75 0.8 1")
    w = dims or WHISK
    r = w["handle_r"]
    g.capsule([0, 0, r], [0, 0, w["handle_len"]], r, rgba="0.1 0.1 0.1 1")
    g.capsule([0, 0, w["handle_len"]], [0, 0, w["head_z"] - w["head_r"] * 0.8], 0.003)
    g.sphere([0, 0, w["head_z"]], w["head_r"], rgba="0.8 0.8 0.85 0.6")
    return body_xml("whisk", pose, g.xml(w["mass"]))


def whisk_rest_tilt(dims: dict | None = None) -> float:
    """Angle of the whisk axis above the table when it lies on its handle end and its head."""
    w = dims or WHISK
    return math.asin((w["head_r"] - w["handle_r"]) / (w["head_z"] - w["handle_r"]))


def container(pose):
    g = GeomSet("container", "0.85 0.85 0.3 1")
    c = CONTAINER
    hx, hy, t, h = c["hx"], c["hy"], c["t"], c["h"]
    _open_box(g, hx, hy, t, h)
    return body_xml("container", pose, g.xml(c["mass"]))


def lid(pose):
    """Lid frame: origin at the centre of the plate's underside."""
    g = GeomSet("lid", "0.9 0.3 0.6 1")
    c = LID
    hx, hy, t, s, st = c["hx"], c["hy"], c["t"], c["skirt"], c["skirt_t"]
    g.box([0, 0, t / 2], [hx, hy, t / 2])
    for sx in (1, -1):
        g.box([sx * (hx - st / 2), 0, -s / 2], [st / 2, hy, s / 2])
    for sy in (1, -1):
        g.box([0, sy * (hy - st / 2), -s / 2], [hx - st, st / 2, s / 2])
    k = c["knob"]
    g.box([0, 0, t + k[2]], k, rgba="0.6 0.15 0.4 1")
    return body_xml("lid", pose, g.xml(c["mass"]))


def vase(pose):
    g = GeomSet("vase", "0.3 0.5 0.8 1")
    v = VASE
    g.cylinder([0, 0, 0.004], v["R"], 0.004)
    g.ring(16, v["R"] - v["t"], v["t"], 0.0, v["h"])
    return body_xml("vase", pose, g.xml(v["mass"]))


def flowers(pose):
    g = GeomSet("flowers", "0.2 0.6 0.2 1")
    f = FLOWERS
    g.box([0, 0, f["base_h"] / 2], [f["base"], f["base"], f["base_h"] / 2])
    g.capsule([0, 0, f["base_h"]], [0, 0, f["top"]], f["stem_r"])
    for sx in (1, -1):
        g.capsule([0, 0, f["base_h"]], [sx * f["side"], 0, f["side_top"]], f["stem_r"])
        g.sphere([sx * f["side"], 0, f["side_top"]], f["blossom_r"], rgba="0.95 0.8 0.1 1")
    g.sphere([0, 0, f["top"]], f["blossom_r"], rgba="0.9 0.2 0.5 1")
    return body_xml("flowers", pose, g.xml(f["mass"]))
