"""Task library core: data classes, keyframe tracks, interpolation, mirroring, scenes and predicates.

The physics replay of a scripted take runs in the simulator: demoforge.lib.sim.replay (the task library
sits below lib/sim, which builds its scenes from these tasks).

Conventions (docs/architecture.md): world = table frame (origin on the table top, z up, y away from
the robot / demonstrator, x to the right); quaternions scalar-last in our arrays, MuJoCo's
scalar-first only in MJCF strings and mocap_quat; arm 0 = left hand, arm 1 = right hand.

Pinch frame (= gripper frame) of a hand: origin midpoint of thumb tip and index tip, z = approach
direction, x = thumb tip -> index tip, y = z x x.

Mirroring: a mirrored take is the exact reflection of the non-mirrored take of the same seed across
the plane x = 0 with the hands swapped.  With M = diag(-1, 1, 1, 1):
  object poses   T' = M T M          (all objects are mirror-symmetric in their local x)
  pinch poses    P' = M P D, D = diag(1, -1, 1, 1)   (a physical reflection of a hand: the thumb
                 stays the thumb, x' = M x, z' = M z, y' = z' x x'); P' differs from M P M only
                 by a 180 degree turn about the approach axis, which a parallel gripper does not see.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from demoforge.lib.errors import UnknownTaskError
from demoforge.lib.geometry import transform_inverse
from demoforge.lib.task_names import TASK_NAMES
from demoforge.lib.trajectories.keyframes import DEFAULT_KEYFRAMES, KeyframeSettings
from demoforge.lib.trajectories.segmentation import Segment  # noqa: F401  (re-exported: Demo.segments hold these)

MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])
HAND_FLIP = np.diag([1.0, -1.0, 1.0, 1.0])
FPS = 30.0
SUBSTEPS = 16  # physics steps per 30 fps frame -> timestep 1/480 s (about 2.1 ms)
UP = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------ small geometry helpers
def make_pose(rot=None, pos=None) -> np.ndarray:
    T = np.eye(4)
    if rot is not None:
        T[:3, :3] = rot.as_matrix() if isinstance(rot, Rotation) else rot
    if pos is not None:
        T[:3, 3] = pos
    return T


inv_pose = transform_inverse  # the scripts' short name for the closed-form SE(3) inverse


def translated(T: np.ndarray, d) -> np.ndarray:
    out = T.copy()
    out[:3, 3] += d
    return out


def unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def frame_zx(z, x) -> np.ndarray:
    """Rotation matrix with approach z and (orthogonalised) closing axis x."""
    z = unit(z)
    x = unit(np.asarray(x, float) - np.dot(x, z) * z)
    return np.stack([x, np.cross(z, x), z], axis=1)


def side_pinch(point, approach, arm: int, pitch: float = 0.0) -> np.ndarray:
    """Pinch pose approaching horizontally along `approach` (xy), pitched down by `pitch` rad.

    Closing axis x is horizontal: for the left hand x = up x z, for the right hand z x up (mirror images).
    """
    h = unit([approach[0], approach[1], 0.0])
    z = math.cos(pitch) * h - math.sin(pitch) * UP
    x = np.cross(UP, h) if arm == 0 else np.cross(h, UP)
    return make_pose(frame_zx(z, x), point)


def top_pinch(point, xdir, tilt_toward=None, tilt: float = 0.0) -> np.ndarray:
    """Pinch pose approaching straight down (optionally tilted), closing along horizontal xdir."""
    z = -UP
    if tilt_toward is not None and tilt:
        h = unit([tilt_toward[0], tilt_toward[1], 0.0])
        z = math.cos(tilt) * z + math.sin(tilt) * h
    return make_pose(frame_zx(z, xdir), point)


def yaw_dir(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw), math.sin(yaw), 0.0])


def object_pose(x: float, y: float, yaw: float, z: float = 0.0, rot: Rotation | None = None) -> np.ndarray:
    r = Rotation.from_euler("z", yaw)
    if rot is not None:
        r = r * rot
    return make_pose(r, [x, y, z])


# ------------------------------------------------------------------ data classes
@dataclass
class Placement:
    """Initial world poses of the task objects, (n_objects, 4, 4), in task.object_names order."""
    object_poses: np.ndarray
    mirror: bool = False

    def mirrored(self) -> "Placement":
        return Placement(MIRROR @ self.object_poses @ MIRROR, not self.mirror)


@dataclass
class Demo:
    task: str
    seed: int
    mirror: bool
    fps: float
    placement: Placement
    pinch_poses: np.ndarray  # (T, 2, 4, 4)
    aperture: np.ndarray  # (T, 2)
    closed: np.ndarray  # (T, 2) bool
    held_object: np.ndarray  # (T, 2) int
    object_poses: np.ndarray  # (T, n_objects, 4, 4) kinematic
    segments: list[Segment]
    fault: str | None = None

    @property
    def n_frames(self) -> int:
        return int(self.pinch_poses.shape[0])

    @property
    def duration(self) -> float:
        return self.n_frames / self.fps

    def keypoints(self) -> np.ndarray:
        return get_task(self.task).keypoints_world(self.object_poses)

    def gripper_actions(self) -> np.ndarray:
        """(T, 2, 8) [x, y, z, qx, qy, qz, qw, g] with g = 1 open, 0 closed (docs/architecture.md)."""
        T = self.n_frames
        out = np.zeros((T, 2, 8))
        out[..., :3] = self.pinch_poses[..., :3, 3]
        out[..., 3:7] = Rotation.from_matrix(self.pinch_poses[..., :3, :3].reshape(-1, 3, 3)).as_quat().reshape(T, 2, 4)
        out[..., 7] = (~self.closed).astype(float)
        return out


@dataclass
class TaskObject:
    name: str
    role: str  # "manipulated" (moved by the acting hand) | "receiving" (held in place by the other hand)
    grasp_width: float  # thumb-index distance when holding, metres
    keypoints: tuple  # ((name, (x, y, z)), ...) in the object's frame
    build: object  # callable(pose) -> MJCF body string
    # turns about its local z axis that map it onto itself (a robot may grasp it turned: sim/robots/retarget.py):
    # 0 any turn (a bottle, a whisk), n >= 1 the n turns of 360 / n degrees (2: a box), 1 none (the default)
    symmetry: int = 1


# ------------------------------------------------------------------ keyframe tracks
class Track:
    """Keyframes of one hand: pinch pose + aperture at knot times, gripper events, interval labels."""

    def __init__(self, pose: np.ndarray, aperture: float):
        self.t = [0.0]
        self.poses = [pose.copy()]
        self.ap = [float(aperture)]
        self.labels: list[tuple[str, int]] = []  # one per interval between knots
        self.events: list[tuple[float, int]] = []  # (time, held object or -1)
        self.hold(0.25, "motion")  # start at rest (zero velocity at t = 0)

    @property
    def now(self) -> float:
        return self.t[-1]

    @property
    def pose(self) -> np.ndarray:
        return self.poses[-1]

    def move(self, dt: float, pose: np.ndarray | None = None, aperture: float | None = None,
             kind: str = "motion", obj: int = -1) -> "Track":
        assert dt > 1e-3
        self.t.append(self.now + dt)
        self.poses.append((self.pose if pose is None else pose).copy())
        self.ap.append(self.ap[-1] if aperture is None else float(aperture))
        self.labels.append((kind, obj))
        return self

    def hold(self, dt: float, kind: str, obj: int = -1) -> "Track":
        return self.move(dt, None, None, kind, obj)

    def until(self, t: float, kind: str, obj: int = -1) -> "Track":
        if t > self.now + 0.02:
            self.hold(t - self.now, kind, obj)
        return self

    def grip(self, obj: int) -> "Track":
        self.events.append((self.now, obj))
        return self

    def release(self) -> "Track":
        self.events.append((self.now, -1))
        return self

    def sample(self, times: np.ndarray):
        knots = np.asarray(self.t)
        poses = np.asarray(self.poses)
        pos = PchipInterpolator(knots, poses[:, :3, 3], axis=0, extrapolate=False)(np.clip(times, 0, knots[-1]))
        q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
        for i in range(1, len(q)):  # same hemisphere as the previous knot
            if np.dot(q[i], q[i - 1]) < 0:
                q[i] = -q[i]
        qi = PchipInterpolator(knots, q, axis=0, extrapolate=False)(np.clip(times, 0, knots[-1]))
        qi /= np.linalg.norm(qi, axis=1, keepdims=True)
        P = np.tile(np.eye(4), (len(times), 1, 1))
        P[:, :3, :3] = Rotation.from_quat(qi).as_matrix()
        P[:, :3, 3] = pos
        ap = PchipInterpolator(knots, np.asarray(self.ap), extrapolate=False)(np.clip(times, 0, knots[-1]))
        held = np.full(len(times), -1, int)
        for te, obj in sorted(self.events, key=lambda e: e[0]):
            held[times >= te - 1e-9] = obj
        idx = np.clip(np.searchsorted(knots, times, side="right") - 1, 0, len(self.labels) - 1)
        kinds = [self.labels[i][0] for i in idx]
        objs = np.array([self.labels[i][1] for i in idx])
        return P, ap, held, kinds, objs


def segments_from_labels(arm: int, kinds: list[str], objs: np.ndarray) -> list[Segment]:
    segs: list[Segment] = []
    for i, k in enumerate(kinds):
        if segs and segs[-1].kind == k:
            segs[-1].end = i + 1
            if k == "motion":  # a motion segment heads for the object of the next skill
                segs[-1].object = int(objs[i])
        else:
            segs.append(Segment(arm, k, i, i + 1, int(objs[i])))
    return segs


def mirror_demo(demo: Demo) -> Demo:
    swap = [1, 0]
    segs = [Segment(1 - s.arm, s.kind, s.start, s.end, s.object) for s in demo.segments]
    segs.sort(key=lambda s: (s.arm, s.start))
    return Demo(
        task=demo.task, seed=demo.seed, mirror=not demo.mirror, fps=demo.fps,
        placement=demo.placement.mirrored(),
        pinch_poses=MIRROR @ demo.pinch_poses[:, swap] @ HAND_FLIP,
        aperture=demo.aperture[:, swap].copy(),
        closed=demo.closed[:, swap].copy(),
        held_object=demo.held_object[:, swap].copy(),
        object_poses=MIRROR @ demo.object_poses @ MIRROR,
        segments=segs, fault=demo.fault,
    )


# ------------------------------------------------------------------ the task base class
class Task:
    name: str = ""
    objects: tuple[TaskObject, ...] = ()
    # xyz min / max box holding every keypoint and pinch position of the scripted takes (hands start at
    # y = -0.16, in front of the table edge), for bounding augmented trajectories
    workspace = np.array([[-0.45, -0.2, 0.0], [0.45, 0.6, 0.65]])
    # xy min / max region where object origins are placed (both the plain and the mirrored layouts)
    placement_region = np.array([[-0.3, 0.12], [0.3, 0.45]])
    faults: tuple[str, ...] = ()  # scripted failure variants for negative tests
    # object name -> (attribute holding its dimension dict, keypoints(dims), grasp width(dims)) for the
    # objects whose size and proportions a variant may change (Task.variant); empty: fixed objects
    resizable: dict = {}
    # how the LLM prompts write this task's action sequences (lib/trajectories/keyframes.py): the
    # coarsest tolerances whose decoded keyframes keep a database's own successes in physics
    # (scripts/measure_keyframes.py); tasks with free-space carries allow coarser ones
    keyframes: KeyframeSettings = DEFAULT_KEYFRAMES

    # -------- static description
    @property
    def object_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.objects)

    @property
    def keypoint_names(self) -> tuple[str, ...]:
        return tuple(k for o in self.objects for k, _ in o.keypoints)

    @property
    def keypoints_local(self) -> np.ndarray:
        return np.array([p for o in self.objects for _, p in o.keypoints], float)

    @property
    def keypoint_object(self) -> np.ndarray:
        return np.array([i for i, o in enumerate(self.objects) for _ in o.keypoints], int)

    @property
    def grasp_widths(self) -> np.ndarray:
        return np.array([o.grasp_width for o in self.objects])

    @property
    def roles(self) -> tuple[str, ...]:
        return tuple(o.role for o in self.objects)

    def object_arm(self, mirror: bool = False) -> np.ndarray:
        """Which arm handles each object: manipulated -> left (0), receiving -> right (1); swapped if mirrored."""
        arms = np.array([0 if o.role == "manipulated" else 1 for o in self.objects])
        return 1 - arms if mirror else arms

    def keypoints_world(self, object_poses: np.ndarray) -> np.ndarray:
        object_poses = np.asarray(object_poses)
        T = object_poses[..., self.keypoint_object, :, :]  # (..., 11, 4, 4)
        return np.einsum("...ij,...j->...i", T[..., :3, :3], self.keypoints_local) + T[..., :3, 3]

    # -------- variants (other object instances, extra bodies)
    def variant(self, dims: dict | None = None, extra_bodies: str = "") -> "Task":
        """A copy of this task with other object dimensions and / or extra bodies in its scene.

        `dims`: {object name: its full dimension dict} for objects in `resizable` (e.g. a wider, shorter
        bottle: demoforge.lib.task_library.objects.scale_dims); the copy's geometry, keypoints, grasp widths,
        scripts and success predicate all use the new dimensions.  `extra_bodies`: MJCF bodies appended
        to every scene of the copy (with _extra_bodies, so free bodies among them are reset with each
        placement by the robot simulator), e.g. distractor objects.  The copy keeps this task's name;
        register it with demoforge.lib.task_library.register_variant to reach it by a name of its own.
        With no arguments the copy behaves exactly like this task."""
        import copy
        import functools

        dims = dict(dims or {})
        unknown = sorted(set(dims) - set(self.resizable))
        if unknown:
            raise ValueError(f"{self.name}: cannot resize {unknown}; resizable objects: "
                             f"{', '.join(self.resizable) or 'none'}")
        t = copy.copy(self)
        objs = []
        for o in self.objects:
            if o.name not in dims:
                objs.append(o)
                continue
            attr, kp_fn, width_fn = self.resizable[o.name]
            d = {k: float(v) for k, v in dims[o.name].items()}
            expected = set(getattr(self, attr))
            if set(d) != expected:
                raise ValueError(f"{self.name}/{o.name}: dimensions must have exactly the keys {sorted(expected)}, "
                                 f"got {sorted(d)}")
            if min(d.values()) <= 0:
                raise ValueError(f"{self.name}/{o.name}: dimensions must be positive, got {d}")
            setattr(t, attr, d)
            objs.append(replace(o, grasp_width=float(width_fn(d)), keypoints=kp_fn(d), build=functools.partial(o.build, dims=d)))
        t.objects = tuple(objs)
        if extra_bodies:
            base_extra = t._extra_bodies  # bound to the copy: resized objects' extras (liquid) follow

            def _extra(placement, _base=base_extra, _more=extra_bodies):
                return _base(placement) + "\n" + _more

            t._extra_bodies = _extra
        return t

    # -------- scene
    def sample_placement(self, rng: np.random.Generator, mirror: bool = False) -> Placement:
        p = Placement(np.asarray(self._sample_poses(rng), float), False)
        return p.mirrored() if mirror else p

    def _sample_poses(self, rng) -> np.ndarray:  # non-mirrored
        raise NotImplementedError

    def _extra_bodies(self, placement: Placement) -> str:
        return ""

    def scene_xml(self, placement: Placement, extra_worldbody: str = "", extra_assets: str = "",
                  extra_equality: str = "") -> str:
        bodies = "\n".join(o.build(P) for o, P in zip(self.objects, placement.object_poses))
        dt = 1.0 / (FPS * SUBSTEPS)
        eq = f"<equality>\n{extra_equality}\n</equality>" if extra_equality else ""
        legs = "\n".join(
            f'<geom name="table_leg{i}" type="box" pos="{sx * 0.68} {0.3 + sy * 0.4} -0.385" size="0.03 0.03 0.365" '
            f'material="table_mat" contype="0" conaffinity="0"/>'
            for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))))
        return f"""<mujoco model="demoforge_{self.name}">
<compiler angle="radian" autolimits="true"/>
<option timestep="{dt:.6g}" integrator="implicitfast" gravity="0 0 -9.81"/>
<default><geom solref="0.005 1"/></default>
<visual><global offwidth="1280" offheight="960"/><quality shadowsize="2048"/>
<headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/></visual>
<asset>
<texture name="floor_tex" type="2d" builtin="checker" rgb1="0.55 0.55 0.55" rgb2="0.45 0.45 0.45" width="256" height="256"/>
<material name="floor_mat" texture="floor_tex" texrepeat="8 8"/>
<material name="table_mat" rgba="0.42 0.46 0.50 1"/>
{extra_assets}
</asset>
<worldbody>
<light name="key" pos="0.3 -0.4 1.6" dir="-0.2 0.3 -1" diffuse="0.7 0.7 0.7" castshadow="true"/>
<light name="fill" directional="true" pos="0 0 2" dir="0 0.2 -1" diffuse="0.3 0.3 0.3" castshadow="false"/>
<geom name="floor" type="plane" pos="0 0 -0.75" size="3 3 0.1" material="floor_mat" contype="2" conaffinity="2"/>
<geom name="table_top" type="box" pos="0 0.3 -0.02" size="0.75 0.45 0.02" material="table_mat" friction="1 0.01 0.001"
 contype="2" conaffinity="2"/>
{legs}
{bodies}
{self._extra_bodies(placement)}
{extra_worldbody}
</worldbody>
{eq}
</mujoco>"""

    # -------- scripted demonstration
    def _script(self, rng: np.random.Generator, poses: np.ndarray, fault: str | None) -> tuple[Track, Track]:
        raise NotImplementedError

    def scripted_demo(self, seed: int, mirror: bool = False, fault: str | None = None) -> Demo:
        """Scripted human take.  `fault` (one of self.faults) makes a deliberately failing variant."""
        if fault is not None and fault not in self.faults:
            raise ValueError(f"unknown fault {fault!r} for {self.name}; known: {self.faults}")
        rng = np.random.default_rng(seed)
        placement = self.sample_placement(rng, mirror=False)
        tracks = self._script(rng, placement.object_poses, fault)
        t_end = max(tr.now for tr in tracks) + 0.3
        T = int(round(t_end * FPS)) + 1
        times = np.arange(T) / FPS
        P = np.zeros((T, 2, 4, 4))
        ap = np.zeros((T, 2))
        held = np.zeros((T, 2), int)
        segs: list[Segment] = []
        for arm, tr in enumerate(tracks):
            P[:, arm], ap[:, arm], held[:, arm], kinds, objs = tr.sample(times)
            segs += segments_from_labels(arm, kinds, objs)
        objp = self.kinematic_objects(placement.object_poses, P, held)
        demo = Demo(self.name, seed, False, FPS, placement, P, ap, held >= 0, held, objp, segs, fault)
        return mirror_demo(demo) if mirror else demo

    @staticmethod
    def kinematic_objects(initial: np.ndarray, P: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Held objects keep their pose relative to the pinch frame from the grasp frame on; a released
        object stays where it was released (kinematically: no falling; physics: demoforge.lib.sim.replay)."""
        T = P.shape[0]
        cur = initial.copy()
        out = np.zeros((T,) + initial.shape)
        rel = [None, None]
        prev = [-1, -1]
        for t in range(T):
            for arm in range(2):
                k = held[t, arm]
                if k >= 0 and k != prev[arm]:
                    rel[arm] = inv_pose(P[t, arm]) @ cur[k]
                if k >= 0:
                    cur[k] = P[t, arm] @ rel[arm]
                prev[arm] = k
            out[t] = cur
        return out

    # -------- success predicate
    def success(self, model, data, history: np.ndarray) -> tuple[bool, str]:
        """Predicate on the simulator: `data` is the final state, `history` the simulated object poses
        (T, n_objects, 4, 4) of the whole run (task objects in object_names order)."""
        raise NotImplementedError


def body_pos(model, data, name: str) -> np.ndarray:
    import mujoco
    return data.xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)].copy()


def local_point(T: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    return T[:3, :3].T @ (np.asarray(p_world) - T[:3, 3])


# ------------------------------------------------------------------ the tasks by name
# The six of the library (TASK_NAMES; registered by tasks.py when the package is imported) and their
# registered variants; Demo.keypoints looks its task up here.

_TASKS: dict[str, Task] = {}
#: Registered task variants (Task.variant), by name: "<task>@<tag>"; looked up by get_task like a task,
#: so code that takes a task name (the robot simulator's scene cache, execute) runs them unchanged.
_VARIANTS: dict[str, Task] = {}


def register_task(task: Task) -> None:
    """Register one of the library's tasks under its name."""
    if task.name not in TASK_NAMES:
        raise ValueError(f"task {task.name!r} is not one of the library's {TASK_NAMES}")
    _TASKS[task.name] = task


def register_variant(task: Task, tag: str) -> str:
    """Register a variant of a task under the name "<task.name>@<tag>" and return that name.  Registering
    the same name again replaces it (variants are deterministic functions of their tag)."""
    if not tag or "@" in tag or not tag.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"variant tag must be a non-empty alphanumeric string (with - or _), got {tag!r}")
    if task.name not in _TASKS:
        raise ValueError(f"variant of unknown task {task.name!r}; known: {TASK_NAMES}")
    key = f"{task.name}@{tag}"
    _VARIANTS[key] = task
    return key


def get_task(name: str) -> Task:
    try:
        return _TASKS[name]
    except KeyError:
        pass
    try:
        return _VARIANTS[name]
    except KeyError:
        hint = " (variants must be registered first: register_variant)" if "@" in str(name) else ""
        raise UnknownTaskError(f"unknown task {name!r}; choose from {', '.join(TASK_NAMES)}{hint}") from None
