"""Simulated scene variations for the thesis's Table 4 (success under clutter, other object instances and
other spatial configurations), as exact, seeded scene descriptions.

    from demoforge.lib.sim.variations import make_variation
    v = make_variation("pouring", "object", seed=0, trial=1)
    v.task()            # the task library variant (resized objects, distractors): geometry, keypoints,
                        # scripts and success predicate all follow the variation
    v.object_poses      # (n_obj, 4, 4) the varied placement
    v.keypoints         # (11, 3) its object keypoints (what retrieval / a prompt sees)
    v.params            # JSON-able description (one table column)

Kinds (VARIATION_KINDS):
  nominal  a seeded placement from the task's own placement distribution (the reference column);
  clutter  the nominal placement plus 2-3 distractor bodies (box / cylinder / sphere, solid, with mass and
           friction) standing on the table around the task objects, clear of their footprints;
  object   the nominal placement with other instances of the task's object categories: even trials
           resize every resizable object uniformly ("size"), odd trials change its proportions ("shape":
           wider and shorter, or narrower and taller: the thesis's shorter-necked bottle);
  spatial  the nominal placement with each object (or group of stacked objects) shifted by 4-8 cm and
           turned by 0.3-0.7 rad about the vertical axis through its footprint.
All kinds of one (task, seed, trial) start from the same nominal placement, so the columns of Table 4
compare the same scenes with and without each variation.

Footprints (object extents on the table) come from the compiled MuJoCo geometry of the (varied) scene,
not from keypoints, so distractors and moved objects are kept clear of the real shapes.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from demoforge.lib.task_library import TASK_NAMES, Placement, Task, get_task, register_variant
from demoforge.lib.task_library import objects as ob

VARIATIONS_VERSION = "1"
VARIATION_KINDS = ("nominal", "clutter", "object", "spatial")
#: the thesis's Table 4 tasks (Pouring, Mix-bowl, Trash-in-bin)
TABLE4_TASKS = ("pouring", "mix_bowl", "trash_in_bin")


@dataclass(frozen=True)
class VariationRanges:
    """Sampling ranges of the variations (metres, radians)."""
    n_distractors: tuple[int, int] = (2, 3)  # inclusive
    distractor_clearance: float = 0.05  # between a distractor's and a task object's footprint: room for fingers
    distractor_region_margin: float = 0.08  # distractors stand in the placement region grown by this much
    size: tuple[float, float] = (0.07, 0.15)  # |s - 1| of a uniform resize
    shape_xy: tuple[float, float] = (0.08, 0.15)  # |s_xy - 1| of a proportion change
    shape_z: tuple[float, float] = (0.12, 0.2)  # |s_z - 1|, opposite sign to s_xy - 1
    max_grasp_width: float = 0.10  # a resized grasp may not exceed this (the grippers open 11 cm)
    shift: tuple[float, float] = (0.04, 0.08)  # spatial: shift distance
    turn: tuple[float, float] = (0.3, 0.7)  # spatial: |yaw change|
    region_margin: float = 0.05  # spatial: object origins stay in the placement region grown by this much
    object_gap: float = 0.01  # minimum gap between footprints of separate task objects
    tries: int = 200


@dataclass(frozen=True)
class Distractor:
    """A solid free body standing on the table: shape box (size = half extents x, y, z), cylinder
    (radius, half height) or sphere (radius,); pose = (x, y) of its footprint centre and yaw."""
    name: str
    shape: str
    size: tuple[float, ...]
    x: float
    y: float
    yaw: float
    mass: float
    rgba: str

    @property
    def radius(self) -> float:
        """Footprint radius on the table."""
        if self.shape == "box":
            return float(math.hypot(self.size[0], self.size[1]))
        return float(self.size[0])

    @property
    def height(self) -> float:
        return float(2 * self.size[2] if self.shape == "box" else 2 * self.size[-1] if self.shape == "cylinder"
                     else 2 * self.size[0])

    def pose(self) -> np.ndarray:
        T = np.eye(4)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        T[:3, 3] = [self.x, self.y, 0.0]
        return T

    def xml(self) -> str:
        g = ob.GeomSet(self.name, self.rgba)
        if self.shape == "box":
            g.box([0, 0, self.size[2]], self.size)
        elif self.shape == "cylinder":
            g.cylinder([0, 0, self.size[1]], self.size[0], self.size[1])
        elif self.shape == "sphere":
            g.sphere([0, 0, self.size[0]], self.size[0])
        else:
            raise ValueError(f"unknown distractor shape {self.shape!r}; use box, cylinder or sphere")
        # solid geoms (objects.SOLID_BITS): they rest on the table and collide with grippers and objects
        return ob.body_xml(self.name, self.pose(), g.xml(self.mass))


@dataclass
class SceneVariation:
    task_name: str
    kind: str
    seed: int
    trial: int
    object_poses: np.ndarray  # (n_obj, 4, 4) varied placement
    nominal_poses: np.ndarray  # (n_obj, 4, 4) the placement every kind of this (task, seed, trial) starts from
    dims: dict = field(default_factory=dict)  # {object: dimension dict} of resized objects
    scales: dict = field(default_factory=dict)  # {object: (s_xy, s_z)}
    distractors: tuple[Distractor, ...] = ()
    moves: dict = field(default_factory=dict)  # spatial: {object: (dx, dy, dyaw)}
    redraws: int = 0  # placements redrawn because resized objects overlapped

    @property
    def params(self) -> dict:
        """JSON-able description of the variation (what the table stores)."""
        return {
            "kind": self.kind,
            "scales": {k: [round(float(v[0]), 4), round(float(v[1]), 4)] for k, v in self.scales.items()},
            "distractors": [{"shape": d.shape, "size": [round(float(s), 4) for s in d.size],
                             "xy": [round(d.x, 4), round(d.y, 4)], "yaw": round(d.yaw, 4), "mass": d.mass}
                            for d in self.distractors],
            "moves": {k: [round(float(x), 4) for x in v] for k, v in self.moves.items()},
            "redraws": self.redraws,
        }

    @property
    def tag(self) -> str:
        """Content tag of the variation (names the registered task variant)."""
        blob = json.dumps({"p": self.params, "s": self.seed, "t": self.trial}, sort_keys=True)
        return f"{self.kind}-{hashlib.sha256(blob.encode()).hexdigest()[:12]}"

    def task(self) -> Task:
        """The task library variant: resized objects and distractor bodies."""
        return get_task(self.task_name).variant(self.dims, "\n".join(d.xml() for d in self.distractors))

    def register(self) -> str:
        """Register task() and return its name ("<task>@<tag>"), usable wherever a task name is."""
        return register_variant(self.task(), self.tag)

    @property
    def keypoints(self) -> np.ndarray:
        return self.task().keypoints_world(self.object_poses)

    def summary(self) -> str:
        """One line for humans."""
        if self.kind == "clutter":
            return ", ".join(f"{d.shape} at ({d.x:.2f}, {d.y:.2f})" for d in self.distractors)
        if self.kind == "object":
            return ", ".join(f"{k} x{s[0]:.2f} wide, x{s[1]:.2f} tall" for k, s in self.scales.items())
        if self.kind == "spatial":
            return ", ".join(f"{k} moved {math.hypot(m[0], m[1]) * 100:.1f} cm, turned {math.degrees(m[2]):+.0f} deg"
                             for k, m in self.moves.items())
        return "the task's own placement distribution"


# ------------------------------------------------------------------ footprints
def object_footprints(task: Task, object_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circles (centres (n_obj, 2), radii (n_obj,)) enclosing each task object's geometry on the table,
    from the compiled scene (each geom's bounding box, turned into the world)."""
    import mujoco

    object_poses = np.asarray(object_poses, float)
    m = mujoco.MjModel.from_xml_string(task.scene_xml(Placement(object_poses)))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    centres, radii = [], []
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    for name in task.object_names:
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        geoms = np.flatnonzero(m.geom_bodyid == b)
        aabb = m.geom_aabb[geoms]  # (g, 6): centre, half sizes in the geom frame
        corners = aabb[:, None, :3] + signs[None] * aabb[:, None, 3:]  # (g, 8, 3)
        R = d.geom_xmat[geoms].reshape(-1, 3, 3)
        world = np.einsum("gij,gkj->gki", R, corners) + d.geom_xpos[geoms][:, None]
        xy = world[..., :2].reshape(-1, 2)
        c = (xy.min(0) + xy.max(0)) / 2
        centres.append(c)
        radii.append(float(np.linalg.norm(xy - c, axis=1).max()))
    return np.array(centres), np.array(radii)


def _overlaps(centres: np.ndarray, radii: np.ndarray, gap: float, groups: list[list[int]] | None = None) -> bool:
    """Any two footprints (of different groups) closer than `gap`."""
    n = len(radii)
    group_of = np.arange(n)
    for gi, g in enumerate(groups or []):
        group_of[g] = gi + n
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    need = radii[:, None] + radii[None] + gap
    other = group_of[:, None] != group_of[None]
    return bool(((dist < need) & other).any())


def footprint_groups(centres: np.ndarray, radii: np.ndarray) -> list[list[int]]:
    """Objects whose footprints overlap in a placement belong together (a lid on its container, flowers in
    their vase): connected components of the overlap graph."""
    n = len(radii)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    adj = dist < radii[:, None] + radii[None]
    groups, seen = [], set()
    for i in range(n):
        if i in seen:
            continue
        stack, comp = [i], []
        while stack:
            j = stack.pop()
            if j in seen:
                continue
            seen.add(j)
            comp.append(j)
            stack += [k for k in np.flatnonzero(adj[j]) if k not in seen]
        groups.append(sorted(comp))
    return groups


# ------------------------------------------------------------------ the variations
def _rng(task_name: str, seed: int, trial: int, *more: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), 104729, int(trial), TASK_NAMES.index(task_name), *more])


def nominal_placement(task_name: str, seed: int, trial: int) -> np.ndarray:
    """(n_obj, 4, 4) the seeded placement all variation kinds of (task, seed, trial) start from."""
    return get_task(task_name).sample_placement(_rng(task_name, seed, trial)).object_poses


def make_variation(task_name: str, kind: str, seed: int, trial: int,
                   ranges: VariationRanges | None = None) -> SceneVariation:
    """The seeded scene of one (task, variation kind, seed, trial); deterministic."""
    if task_name not in TASK_NAMES:
        raise ValueError(f"unknown task {task_name!r}; choose from {', '.join(TASK_NAMES)}")
    if kind not in VARIATION_KINDS:
        raise ValueError(f"unknown variation kind {kind!r}; choose from {', '.join(VARIATION_KINDS)}")
    r = ranges or VariationRanges()
    nominal = nominal_placement(task_name, seed, trial)
    rng = _rng(task_name, seed, trial, VARIATION_KINDS.index(kind) + 1)
    v = SceneVariation(task_name, kind, int(seed), int(trial), nominal.copy(), nominal)
    if kind == "clutter":
        v.distractors = _distractors(get_task(task_name), nominal, rng, r)
    elif kind == "object":
        _resize(v, rng, r)
    elif kind == "spatial":
        _move(v, rng, r)
    return v


def _signed(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    return float(rng.uniform(*lo_hi) * rng.choice([-1.0, 1.0]))


def _resize(v: SceneVariation, rng: np.random.Generator, r: VariationRanges) -> None:
    base = get_task(v.task_name)
    if not base.resizable:
        raise ValueError(f"task {v.task_name!r} has no resizable objects (the object variation needs "
                         f"Task.resizable); tasks with them: "
                         f"{', '.join(n for n in TASK_NAMES if get_task(n).resizable)}")
    mode = "size" if v.trial % 2 == 0 else "shape"
    for name, (attr, _kp, width_fn) in base.resizable.items():
        d0 = getattr(base, attr)
        if mode == "size":
            s_xy = s_z = 1.0 + _signed(rng, r.size)
        else:
            dxy = _signed(rng, r.shape_xy)
            s_xy, s_z = 1.0 + dxy, 1.0 - math.copysign(rng.uniform(*r.shape_z), dxy)
        w0 = float(width_fn(d0))
        if w0 * s_xy > r.max_grasp_width and width_fn(ob.scale_dims(name, d0, 2.0, 1.0)) > w0:
            s_xy = r.max_grasp_width / w0  # the grasp scales with the object: keep it within the gripper
            if mode == "size":
                s_z = s_xy
        v.scales[name] = (float(s_xy), float(s_z))
        v.dims[name] = ob.scale_dims(name, d0, s_xy, s_z)
    task = v.task()
    # the same draw as the nominal placement (a resized lying whisk rests at another height); redraw
    # only if the resized objects would overlap
    poses = task.sample_placement(_rng(v.task_name, v.seed, v.trial)).object_poses
    c0, r0 = object_footprints(base, v.nominal_poses)
    groups = footprint_groups(c0, r0)
    for k in range(r.tries):
        c, rad = object_footprints(task, poses)
        if not _overlaps(c, rad, r.object_gap, groups):
            v.object_poses, v.redraws = poses, k
            return
        poses = task.sample_placement(rng).object_poses
    raise RuntimeError(f"{v.task_name}: no overlap-free placement of the resized objects {v.scales} in "
                       f"{r.tries} draws; narrow VariationRanges.size / shape_xy")


def _move(v: SceneVariation, rng: np.random.Generator, r: VariationRanges) -> None:
    task = get_task(v.task_name)
    c0, r0 = object_footprints(task, v.nominal_poses)
    groups = footprint_groups(c0, r0)
    lo = task.placement_region[0] - r.region_margin
    hi = task.placement_region[1] + r.region_margin
    for _ in range(r.tries):
        poses = v.nominal_poses.copy()
        moves = {}
        for g in groups:
            ang = rng.uniform(0, 2 * math.pi)
            dist = rng.uniform(*r.shift)
            shift = dist * np.array([math.cos(ang), math.sin(ang)])
            yaw = _signed(rng, r.turn)
            c = c0[g].mean(axis=0)
            cs, sn = math.cos(yaw), math.sin(yaw)
            Rz = np.array([[cs, -sn, 0], [sn, cs, 0], [0, 0, 1.0]])
            for k in g:  # turn about the group's vertical axis, then shift
                T = poses[k]
                T[:3, :3] = Rz @ T[:3, :3]
                T[:2, 3] = c + Rz[:2, :2] @ (T[:2, 3] - c) + shift
                moves[task.object_names[k]] = (float(shift[0]), float(shift[1]), float(yaw))
        origins = poses[:, :2, 3]
        if (origins < lo).any() or (origins > hi).any():
            continue
        c, rad = object_footprints(task, poses)
        if _overlaps(c, rad, r.object_gap, groups):
            continue
        v.object_poses, v.moves = poses, moves
        return
    raise RuntimeError(f"{v.task_name}: no valid moved placement in {r.tries} draws; narrow VariationRanges.shift")


_DISTRACTOR_KINDS = (  # (shape, size ranges, mass kg, colour): a tea box, a mug-sized tin, a fruit
    ("box", ((0.025, 0.04), (0.02, 0.035), (0.03, 0.06)), 0.15, "0.55 0.35 0.7 1"),
    ("cylinder", ((0.025, 0.04), (0.03, 0.055)), 0.20, "0.2 0.55 0.55 1"),
    ("sphere", ((0.03, 0.04),), 0.10, "0.9 0.5 0.1 1"),
)


def _distractors(task: Task, poses: np.ndarray, rng: np.random.Generator, r: VariationRanges) -> tuple[Distractor, ...]:
    centres, radii = object_footprints(task, poses)
    lo = task.placement_region[0] - r.distractor_region_margin
    hi = task.placement_region[1] + r.distractor_region_margin
    n = int(rng.integers(r.n_distractors[0], r.n_distractors[1] + 1))
    out: list[Distractor] = []
    for i in range(n):
        shape, ranges, mass, rgba = _DISTRACTOR_KINDS[int(rng.integers(len(_DISTRACTOR_KINDS)))]
        size = tuple(float(rng.uniform(*lh)) for lh in ranges)
        for _ in range(r.tries):
            xy = rng.uniform(lo, hi)
            d = Distractor(f"distractor_{i}", shape, size, float(xy[0]), float(xy[1]),
                           float(rng.uniform(-math.pi, math.pi)), mass, rgba)
            clear_objects = (np.linalg.norm(centres - xy, axis=1) >= radii + d.radius + r.distractor_clearance).all()
            clear_others = all(math.hypot(o.x - d.x, o.y - d.y) >= o.radius + d.radius + r.object_gap for o in out)
            if clear_objects and clear_others:
                out.append(d)
                break
        else:
            raise RuntimeError(f"{task.name}: no free table spot for distractor {i} in {r.tries} draws; "
                               "lower VariationRanges.n_distractors or distractor_clearance")
    return tuple(out)


__all__ = ["VARIATIONS_VERSION", "VARIATION_KINDS", "TABLE4_TASKS", "VariationRanges", "Distractor",
           "SceneVariation", "make_variation", "nominal_placement", "object_footprints", "footprint_groups"]
