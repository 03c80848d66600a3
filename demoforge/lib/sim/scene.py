"""Compiled robot scenes: a task library scene plus a robot (lib/sim/robots), compiled once per process.

`get_scene(task_name, robot, physics)` returns a cached `SimScene` (MjModel + MjData + index tables);
episodes only reset the MjData and write object / robot placements into qpos, so thousands of
episodes never recompile XML.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from demoforge.lib.geometry import matrix_to_quat, xyzw_to_wxyz
from demoforge.lib.task_library import Placement, Task, get_task

from .gripper import GripperSpec
from .robots import NO_ARM, PART_LINK, Robot
from .robots.base import as_index
from .robots.grippers import GrippersRobot

# geom owner codes (SimScene.geom_code)
CODE_OTHER = 0
CODE_TABLE = 1  # table top and floor
CODE_OBJECT = 10  # + object index
CODE_GRIPPER = 100  # + 10 * arm + part (0 left finger, 1 right finger, 2 palm / wrist, 3 arm link)
# geom pair kinds (SimScene.pair_kind)
# -, left-right gripper, gripper-object, gripper-table, arm link-(table, object, other arm)
PAIR_NONE, PAIR_ARMS, PAIR_TOUCH, PAIR_TABLE, PAIR_LINK = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class PhysicsOptions:
    """Solver settings applied to the compiled model.

    timestep stays the task library's 1/480 s. Coarser steps were tried and rejected because they
    change outcomes of marginal grasps although all 72 scripted demos (six tasks x seeds 0-5 x
    mirror) still succeed: at 1/360 s (25 % fewer steps) 20 ingested pouring episodes went from
    14 to 6 successes (refsafe stretches the 5 ms contacts to 5.6 ms: a tilted bottle slips), and
    with refsafe off open_container went from 0 to 20 of 20; at 1/240 s empty_vase lost 3 of 12
    scripted demos. `LEGACY_PHYSICS` keeps the previous settings (the benchmark's baseline)."""
    timestep: float = 1.0 / 480.0
    iterations: int = 50
    ls_iterations: int = 20
    noslip_iterations: int = 0
    tolerance: float = 1e-8
    sleep_tolerance: float = 0.0  # > 0: MuJoCo's body sleeping (mjENBL_SLEEP) with this velocity tolerance
    # implicitfast (the task library's), not Euler: Euler would save ~10 % of a step, but it treats the
    # finger drive's damping (kv) explicitly, and with the tendon's effective mass (~0.03 kg) that is
    # stable only for dt < 2 m / kv = 1.7 ms: the fingers chatter at a joint limit (qvel ~0.9 m/s at
    # rest, seen at 1/360 s) although the scripted demos' outcomes did not change
    integrator: str = "implicitfast"  # "euler" | "implicitfast" | "implicit" | "rk4"
    # island discovery off: the scenes have 2-4 kinematic trees, usually coupled through contacts,
    # so partitioning the constraint problem costs more than it saves (mj_step from mid-episode
    # states: 0.85-0.94 x the time per step; whole episodes on the loaded 2-core machine: within
    # noise). Outcomes: 72/72 scripted demos; 20 ingested pouring / open_container episodes 15 / 0
    # successes, legacy 14 / 0
    islands: bool = False
    # MuJoCo's refsafe clamps a contact time constant below 2 dt up to 2 dt (softer contacts); False
    # keeps the scene's own 5 ms contacts at timesteps above 2.5 ms (mjDSBL_REFSAFE)
    refsafe: bool = True


LEGACY_PHYSICS = PhysicsOptions(islands=True)  # before the speed work (benchmark baseline)


def as_robot(robot: Robot | GripperSpec | None) -> Robot:
    """A robot (a bare GripperSpec means the floating grippers with that hand; None the default robot)."""
    if robot is None:
        return GrippersRobot()
    if isinstance(robot, GripperSpec):
        return GrippersRobot(robot)
    return robot


def robot_scene(task_name: str | Task, robot: Robot | GripperSpec | None = None,
                placement: Placement | None = None) -> tuple[str, dict]:
    """(MJCF, assets) of a task's scene (a task's name, or a Task such as an unregistered variant) with the
    robot added, its objects at `placement` (default the reference placement: episodes move the free
    bodies); assets: the files the MJCF names (meshes), for MuJoCo's compiler."""
    robot = as_robot(robot)
    name, task = (task_name, get_task(task_name)) if isinstance(task_name, str) else (task_name.name, task_name)
    ref = placement if placement is not None else task.sample_placement(np.random.default_rng(0))
    sec = robot.scene_parts(name)
    xml = task.scene_xml(ref, extra_worldbody=sec.worldbody, extra_equality=sec.equality,
                         extra_assets=sec.asset_xml)
    tail = (f"<tendon>\n{sec.tendon}\n</tendon>\n<actuator>\n{sec.actuator}\n</actuator>\n"
            f"<contact>\n{sec.contact}\n</contact>\n</mujoco>")
    i = xml.rstrip().rfind("</mujoco>")
    return xml[:i] + tail, dict(sec.assets)


class SimScene:
    """A task's scene with a robot, compiled: the model, its data and the executor's index tables.

    physics None keeps the solver options the MJCF writes (the scripted replay's, replay.py); placement:
    where the MJCF puts the objects (default the reference placement; SimScene.reset moves them)."""

    def __init__(self, task_name: str | Task, robot: Robot, physics: PhysicsOptions | None,
                 placement: Placement | None = None):
        import mujoco

        self.mj = mujoco
        # the name the robot is bound under: a registered variant's own ("pouring@wide"), a Task's name otherwise
        key, task = (task_name, get_task(task_name)) if isinstance(task_name, str) else (task_name.name, task_name)
        self.task = task
        self.robot = robot
        self.spec = robot.gripper
        self.physics = physics
        self.xml, assets = robot_scene(task_name, robot, placement)
        m = mujoco.MjModel.from_xml_string(self.xml, assets) if assets else mujoco.MjModel.from_xml_string(self.xml)
        if physics is not None:
            self._apply_physics(m, physics)
        self.model = m
        self.data = mujoco.MjData(m)
        self.binding = rb = robot.bind(m, key)

        def bid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)

        def free_adr(body):
            j = m.body_jntadr[body]
            return int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])

        self.n_obj = len(task.objects)
        self.obj_body = np.array([bid(n) for n in task.object_names])
        self.obj_qadr = np.array([free_adr(b)[0] for b in self.obj_body])
        self.obj_vadr = np.array([free_adr(b)[1] for b in self.obj_body])
        self.finger_qadr = rb.finger_qadr
        self.act = rb.grip_act
        self.act_index = as_index(rb.grip_act)  # a slice where contiguous: the frame loop's finger writes
        # free bodies that are neither task objects nor the robot's (e.g. the pouring liquid)
        known = set(task.object_names) | set(rb.bodies)
        self.extra_names = []
        self.extra_qadr = []
        self.extra_vadr = []
        for b in range(1, m.nbody):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)
            j = m.body_jntadr[b]
            if name in known or j < 0 or m.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
                continue
            self.extra_names.append(name)
            self.extra_qadr.append(int(m.jnt_qposadr[j]))
            self.extra_vadr.append(int(m.jnt_dofadr[j]))
        # dofs of the executor's "scene at rest" test (one gather each): linear = translations of every
        # free body (objects, extras) and the robot's (its free bases, finger slides); angular = rotations
        # of the objects and the robot's (gripper bases, arm joints). The extras' (liquid spheres') spin is
        # left out: packed spheres keep spinning in place in contact jitter, and only their positions matter.
        free = np.concatenate([self.obj_vadr, np.asarray(self.extra_vadr, np.int64)]).astype(np.int64)
        self.rest_lin = np.concatenate([(free[:, None] + np.arange(3)).ravel(), rb.rest_lin]).astype(np.int64)
        self.rest_ang = np.concatenate([(self.obj_vadr[:, None] + np.arange(3, 6)).ravel(), rb.rest_ang]).astype(np.int64)
        self._contact_tables(m, mujoco)
        self.workspace = np.asarray(task.workspace, float)

    @staticmethod
    def _apply_physics(m, physics: PhysicsOptions) -> None:
        import mujoco

        m.opt.timestep = physics.timestep
        m.opt.iterations = physics.iterations
        m.opt.ls_iterations = physics.ls_iterations
        m.opt.noslip_iterations = physics.noslip_iterations
        m.opt.tolerance = physics.tolerance
        integrators = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4,
                       "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
                       "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}
        if physics.integrator not in integrators:
            raise ValueError(f"PhysicsOptions.integrator must be one of {sorted(integrators)}, got {physics.integrator!r}")
        m.opt.integrator = int(integrators[physics.integrator])
        if not physics.refsafe:
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_REFSAFE)
        if not physics.islands:
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
        if physics.sleep_tolerance > 0:
            m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
            m.opt.sleep_tolerance = physics.sleep_tolerance

    def _contact_tables(self, m, mujoco) -> None:
        """Geom owner codes and, per geom pair, what a contact between them means for the executor."""
        rb = self.binding
        code = np.zeros(m.ngeom, np.int64)
        obj_of_body = {int(b): k for k, b in enumerate(self.obj_body)}
        for g in range(m.ngeom):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
            b = int(m.geom_bodyid[g])
            if name in ("table_top", "floor"):
                code[g] = CODE_TABLE
            elif b in obj_of_body:
                code[g] = CODE_OBJECT + obj_of_body[b]
            elif rb.geom_arm[g] != NO_ARM:
                code[g] = CODE_GRIPPER + 10 * rb.geom_arm[g] + rb.geom_part[g]
        self.geom_code = code
        # per geom pair (symmetric): what a contact between them means for the executor's bookkeeping,
        # so that the per-control-step contact scan is one table look-up (executor.contacts)
        g = code >= CODE_GRIPPER
        arm = np.where(g, (code - CODE_GRIPPER) // 10, -1)
        obj = np.where((code >= CODE_OBJECT) & (code < CODE_GRIPPER), code - CODE_OBJECT, -1)
        kind = np.zeros((m.ngeom, m.ngeom), np.int8)
        kind[np.ix_(g, g)] = PAIR_ARMS * (arm[g][:, None] != arm[g][None, :])
        for a_, b_ in ((g, obj >= 0), (obj >= 0, g)):
            kind[np.ix_(a_, b_)] = PAIR_TOUCH
        for a_, b_ in ((g, code == CODE_TABLE), (code == CODE_TABLE, g)):
            kind[np.ix_(a_, b_)] = PAIR_TABLE
        # an arm link (not a hand) touching the table, an object or any geom of the other arm
        link = g & ((code - CODE_GRIPPER) % 10 == PART_LINK)
        hit = (code == CODE_TABLE) | (obj >= 0)
        for a_, b_ in ((link, hit), (hit, link)):
            kind[np.ix_(a_, b_)] = PAIR_LINK
        other = g[None, :] & (arm[:, None] != arm[None, :])
        kind[(link[:, None] & other) | (link[None, :] & other.T)] = PAIR_LINK
        gi, gj = np.meshgrid(np.arange(m.ngeom), np.arange(m.ngeom), indexing="ij")
        grip_geom = np.where(g[gi], gi, gj)  # the robot geom of a robot-x pair (the first of two robot geoms)
        other_geom = np.where(g[gi], gj, gi)
        self.pair_kind = kind
        self.pair_arm = arm[grip_geom].astype(np.int64)
        self.pair_part = np.where(g[grip_geom], (code[grip_geom] - CODE_GRIPPER) % 10, 0).astype(np.int64)
        self.pair_obj = np.maximum(obj[other_geom], 0).astype(np.int64)
        # the same tables as flat Python lists: the per-contact look-up in the executor's hot loop is a
        # list index (~30 ns) instead of a NumPy scalar index (~100 ns plus a boxed scalar)
        self.pair_lists = tuple(x.ravel().tolist() for x in (self.pair_kind, self.pair_arm, self.pair_part,
                                                             self.pair_obj))

    # ------------------------------------------------------------------ placement
    def extra_poses(self, object_poses: np.ndarray) -> np.ndarray:
        """World poses (k, 7: pos + wxyz) of the extra free bodies for this placement (exact, from the
        task library's own _extra_bodies MJCF for the placement)."""
        if not self.extra_names:
            return np.zeros((0, 7))
        frag = self.task._extra_bodies(Placement(np.asarray(object_poses, float)))
        root = ET.fromstring(f"<root>{frag}</root>")
        found = {}
        for el in root.iter("body"):
            pos = np.array([float(v) for v in el.get("pos", "0 0 0").split()])
            quat = np.array([float(v) for v in el.get("quat", "1 0 0 0").split()])
            found[el.get("name")] = np.concatenate([pos, quat])
        return np.stack([found[n] for n in self.extra_names])

    def reset(self, object_poses: np.ndarray | None, pose0: np.ndarray, width0: np.ndarray, plan=None) -> None:
        """Reset MjData: objects at object_poses (n_obj, 4, 4) (None: where the MJCF puts them, exactly as
        compiled), the robot in its plan's first state with its pinch points at pose0 (2, 7 xyzw) and
        apertures width0 (2,)."""
        mj, m, d = self.mj, self.model, self.data
        mj.mj_resetData(m, d)
        if object_poses is not None:
            self.place_objects(d, object_poses)
        self.binding.reset(d, plan, pose0, width0)
        mj.mj_forward(m, d)

    def place_objects(self, d, object_poses: np.ndarray) -> None:
        """The objects (n_obj, 4, 4) and the extra free bodies of that placement into MjData d's qpos."""
        q = xyzw_to_wxyz(matrix_to_quat(object_poses[:, :3, :3]))
        for k in range(self.n_obj):
            a = self.obj_qadr[k]
            d.qpos[a:a + 3] = object_poses[k, :3, 3]
            d.qpos[a + 3:a + 7] = q[k]
        for a, pq in zip(self.extra_qadr, self.extra_poses(object_poses)):
            d.qpos[a:a + 7] = pq


_CACHE: dict = {}


def get_scene(task_name: str, robot: Robot | GripperSpec | None = None, physics: PhysicsOptions | None = None) -> SimScene:
    """Per-process cache of compiled scenes keyed by (task, robot, physics options)."""
    key = (task_name, as_robot(robot), physics or PhysicsOptions())
    sc = _CACHE.get(key)
    if sc is None:
        sc = _CACHE[key] = SimScene(*key)
    return sc


def clear_cache() -> None:
    _CACHE.clear()
