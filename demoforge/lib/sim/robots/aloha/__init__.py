"""The `aloha` robot: two ViperX 300 6-DOF arms (gym-aloha's model) executing episodes in joint space.

Per episode (lib/sim/robots/arm_motion.py): the demonstrated poses are smoothed, each arm's window (from
its first skill segment to its last) is made the arms' own (retargeting.py: the held object's motion kept,
the grasp turned about the object's symmetry axis as grasp_choice.py finds best for the ViperX over the
whole window, the fingertips kept above the table), both arms start at their ready pose (gym-aloha's start
pose, `REST`), move in joint space into their window (transits checked for clearance) and follow it through
inverse kinematics (lib/sim/robots/ik.py: mink with its collision limits, each step started from the
closed-form joints of closed_form.py), and move back to the ready pose after it; the whole joint
trajectory is slowed wherever a joint would exceed its servo's speed (lib/sim/robots/retiming.py). The
arms' position actuators follow it, interpolated linearly between the executed frames at the control
rate; the fingers get the same force-limited finger command as the grippers. A step of a window whose
pose the IK cannot reach within 1 cm and 5 degrees is a hard failure (`unreachable`, or `joint_limit` with
a joint at the end of its range) at that step; an arm link touching the table, an object or the other
arm is `link_collision` (lib/sim/failures.py). screening.py checks whole databases the same way without
physics.

Hands (`hand`): `aloha`, the ViperX gripper with ALOHA's fingers (69 mm between the pads fully open);
`2f140`, the Robotiq 2F-140 of the floating grippers on the wrist (the thesis's "6-DOF arm with a
parallel gripper" that fits every object of the task library).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from demoforge.lib.sim.gripper import GripperSpec
from demoforge.lib.sim.robots import ik
from demoforge.lib.sim.robots.base import (NO_ARM, PART_FINGER_L, PART_FINGER_R, PART_LINK, PART_PALM, Execution,
                                           MotionPlan, PlanEvent, Robot, RobotBinding, SceneParts, as_index)

from demoforge.lib.sim.robots.arm_motion import plan_arm_motion
from demoforge.lib.sim.robots.ik import ArmsIK
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.keyframes import smooth_actions

from .closed_form import ViperXBatchIK
from .model import JOINTS, KP, KV, REST, SIDES, SPEED, BasePose, arms_parts, hand_spec, kinematic_model_xml, mesh_assets
from .placement import bases_for
from .retargeting import NO_GUESS_WRIST, ArmsRetargeting
from .seeds import ViperXGeometry

HANDS = ("aloha", "2f140")
# 2: the simulator's IK stops at the first failing step; 3: ready-pose start, transits, symmetric orientation,
# time-scaling instead of speed clipping; 4: a window's candidates refined until they stop improving; 5: smoothed
# poses, each window's grasp chosen among the held object's symmetric turns, fingers kept above the table; 6: the
# grasp chosen as a path over turns and branches clear of the other arm, transits with clearance, the path checked
# as finally run; 7: a grasp path forced across a joint jump is not feasible; 8: mink collision limits and posture
# task, fingertips 2 mm above the table, a thin held object turns only in a hand that grips it; 9: the held
# object named by hull distance (a stem pinched above the vase's rim is the flowers', not the vase's); 10: never
# again (a reverted wait before each close used it: its cached results must not match); 11: a released arm drawn
# back towards its base; 12: empty_vase's bases; 13: the waist turned first on a transit; 14: the transit check's
# workspace. Bump when the motion (ik.py, arm_motion.py, retiming.py, seeds.py) gives other joints for the same poses
IK_VERSION = "14"
# mink's collision limits in the IK (lib/sim/robots/ik.py): the two forearms, wrists and hands apart, every link
# from the upper arm on above the table top; (geoms, geoms, distance kept m)
_FOREARM = ("5_lower_forearm", "6_wrist", "7_gripper")
_LINKS = ("3_upper_arm", "4_upper_forearm", "5_lower_forearm", "6_wrist", "7_gripper")
COLLISION_PAIRS = ((tuple(f"left_{g}" for g in _FOREARM), tuple(f"right_{g}" for g in _FOREARM), 0.02),
                   (tuple(f"{s}_{g}" for s in SIDES for g in _LINKS), ("table_top",), 0.01))
POSTURE_COST = 1e-3  # mink's posture task towards the ready pose (the pose tasks leave an arm no freedom to spare)
TRANSIT_CLEARANCE = 0.04  # m: contact margin of the transit check (MuJoCo honours it only partly for box pairs)
SMOOTH_SIGMA = 2.0  # steps: the Gaussian the demonstrated poses are smoothed with before the arms follow them
LEAD = np.array([kv / kp for kp, kv in zip(KP, KV)] * 2)  # s: each joint's damping-to-stiffness ratio
#: the joint-space export's 14 values, named as the ALOHA datasets name them
JOINT_NAMES = tuple(f"{side}_{j}" for side in SIDES for j in (*JOINTS, "gripper"))


@dataclass(frozen=True)
class AlohaRobot(Robot):
    hand: str = "aloha"
    # (left, right) base poses for every task; None: each task's own (placement.py)
    bases: tuple[BasePose, BasePose] | None = None

    name: ClassVar[str] = "aloha"
    joint_names: ClassVar[tuple[str, ...]] = JOINT_NAMES

    def __post_init__(self):
        if self.hand not in HANDS:
            raise ValueError(f"the aloha robot carries {' or '.join(HANDS)}, not {self.hand!r}")

    @property
    def gripper(self) -> GripperSpec:
        return hand_spec(self.hand)

    @property
    def gripper_name(self) -> str:
        return self.hand

    @property
    def label(self) -> str:
        return self.name if self.hand == "aloha" else f"{self.name}+{self.hand}"

    def bases_for(self, task_name: str) -> tuple[BasePose, BasePose]:
        return self.bases if self.bases is not None else bases_for(get_task(task_name).name)

    def scene_parts(self, task_name: str) -> SceneParts:
        sec = arms_parts(self.bases_for(task_name), self.hand, self.gripper)
        mesh_xml, files = mesh_assets()
        return SceneParts(worldbody=sec["worldbody"], equality=sec["equality"], tendon=sec["tendon"],
                          actuator=sec["actuator"], contact=sec["contact"], asset_xml=mesh_xml, assets=files)

    def bind(self, model, task_name: str) -> "AlohaBinding":
        return AlohaBinding(model, self, task_name)

    def settings(self, task_name: str) -> str:
        return (f"ik {IK_VERSION}: speed {SPEED}, ready {REST}, tolerance {ik.POSITION_TOL} m {ik.ROTATION_TOL_DEG} deg, "
                f"converged {ik.CONVERGED_POSITION} m {ik.CONVERGED_ROTATION} rad, iterations {ik.TRIES} tries, "
                f"feed-forward {LEAD.tolist()}")

    def ik(self, task_name: str):
        """The task's IK solver (one per process and placement)."""
        key = (self.hand, self.bases_for(task_name))
        solver = _IK_CACHE.get(key)
        if solver is None:
            solver = _IK_CACHE[key] = _make_ik(self.bases_for(task_name), self.hand, self.gripper)
        return solver

    def retargeting(self, task_name: str) -> ArmsRetargeting:
        """The task's retargeting (aloha/retargeting.py: each window's grasp, the table clearance)."""
        key = (self.hand, self.bases_for(task_name), task_name)
        r = _RETARGET_CACHE.get(key)
        if r is None:
            solver = self.ik(task_name)
            batch = ViperXBatchIK(ViperXGeometry(solver.model), solver.lower[:6], solver.upper[:6])
            r = _RETARGET_CACHE[key] = ArmsRetargeting(batch, self.bases_for(task_name), np.array(REST * 2),
                                                       solver.speed, get_task(task_name), self.gripper)
        return r

    def motion(self, task_name: str, actions: np.ndarray, object_keypoints: np.ndarray, fps: float = 30.0,
               until_failure: bool = False, collides=None):
        """The arms' motion for an episode (lib/sim/robots/arm_motion.py): what they execute of its (n, 2, 8)
        actions with the objects' keypoints (K, 3) at its start; collides: the transits' collision check
        (AlohaBinding.collision_check; None: unchecked). The actions are smoothed first (SMOOTH_SIGMA: the
        ingested pinch point jitters by about 1 cm from frame to frame), then retargeted (retargeting.py)."""
        retarget = self.retargeting(task_name)
        smooth = smooth_actions(actions, SMOOTH_SIGMA)
        return plan_arm_motion(self.ik(task_name), smooth, object_keypoints, get_task(task_name).keypoint_object,
                               fps, np.array(REST * 2), until_failure, collides,
                               retarget=lambda a, w: retarget(a, w, object_keypoints))

    def joint_values(self, execution: Execution) -> np.ndarray:
        """(m, 14) joint values of an episode as the arms execute it (AlohaBinding.prepare) and the joint-space
        export writes it: per arm the six joints, then the gripper's normalized opening (1 open, 0 closed:
        the g of the demonstrated step each executed frame has reached)."""
        motion = execution.state
        out = np.zeros((len(motion.q), 14))
        for a in range(2):
            out[:, 7 * a:7 * a + 6] = motion.q[:, 6 * a:6 * a + 6]
            out[:, 7 * a + 6] = np.clip(motion.poses[:, a, 7], 0.0, 1.0)
        return out


_IK_CACHE: dict = {}
_RETARGET_CACHE: dict = {}


def _make_ik(bases: tuple[BasePose, BasePose], hand: str, spec: GripperSpec):
    xml, files = kinematic_model_xml(bases, hand, spec)
    geometry = []

    def arm_seeds(arm: int, pose: np.ndarray) -> list[np.ndarray]:
        """The arm's geometric solutions (seeds.py) for a pinch pose [x y z qx qy qz qw]."""
        if not geometry:
            geometry.append(ViperXGeometry(solver.model))
        return geometry[0].solutions(bases[arm], pose)

    def out_of_reach(poses: np.ndarray) -> np.ndarray:
        """(n, 2): the pinch target is farther from the shoulder joint than the stretched arm reaches."""
        g = geometry[0] if geometry else ViperXGeometry(solver.model)
        reach = g.l1 + g.l2 + g.wrist_to_pinch
        out = np.zeros(poses.shape[:2], bool)
        for a, base in enumerate(bases):
            shoulder = base.matrix()[:3, :3] @ np.array([0.0, 0.0, g.shoulder_z]) + base.matrix()[:3, 3]
            out[:, a] = np.linalg.norm(poses[:, a, :3] - shoulder, axis=1) > reach
        return out

    def analytic(arm: int, pos: np.ndarray, R: np.ndarray, near: np.ndarray) -> np.ndarray:
        """The closed-form solution (closed_form.py) nearest `near` (m, 6) for pinch poses pos, R (NaN rows where
        the wrist is nearly straight)."""
        if not geometry:
            geometry.append(ViperXGeometry(solver.model))
        sol = ViperXBatchIK(geometry[0], solver.lower[:6], solver.upper[:6]).solve(bases[arm], pos, R)
        b = np.abs(sol.q - np.asarray(near)[:, None]).max(axis=-1).argmin(axis=1)
        q = sol.q[np.arange(len(pos)), b]
        q[np.abs(np.sin(q[:, 4])) < NO_GUESS_WRIST] = np.nan  # a nearly straight wrist: its rolls are one angle
        return q

    solver = ArmsIK(xml, files, sites=[f"{s}_hand_pinch" for s in SIDES], arm_joints=(range(6), range(6, 12)),
                    speed=SPEED * 2, arm_seeds=arm_seeds, rest=np.array(REST * 2), out_of_reach=out_of_reach,
                    analytic=analytic, collision_pairs=COLLISION_PAIRS, posture_cost=POSTURE_COST)
    return solver


class _JointPlan(MotionPlan):
    """Each control step commands the arms' joints, interpolated between the IK solutions of the frames."""

    def __init__(self, act, q_ctrl: np.ndarray, q0: np.ndarray, events: list, summary: dict):
        self.act, self.q_ctrl, self.q0 = act, q_ctrl, q0
        self.events, self.summary = events, summary

    def apply(self, d, k: int) -> None:
        d.ctrl[self.act] = self.q_ctrl[k]


class AlohaBinding(RobotBinding):
    hand_workspace_slack = 0.15
    def __init__(self, m, robot: AlohaRobot, task_name: str):
        import mujoco

        self.robot, self.task_name = robot, task_name
        self.spec = robot.gripper

        def jid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

        arm_joints = [jid(f"{s}_{j}") for s in SIDES for j in JOINTS]
        self.arm_qadr = np.array([m.jnt_qposadr[j] for j in arm_joints])
        arm_dofs = np.array([m.jnt_dofadr[j] for j in arm_joints])
        self.arm_act = as_index([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{s}_{j}") for s in SIDES
                                 for j in JOINTS])
        self.finger_qadr = np.array([[m.jnt_qposadr[jid(f"{s}_hand_{f}")] for f in "lr"] for s in SIDES])
        self.grip_act = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{s}_hand_grip") for s in SIDES])
        self.pinch = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{s}_hand_pinch") for s in SIDES])
        fing = np.array([m.jnt_dofadr[jid(f"{s}_hand_{f}")] for s in SIDES for f in "lr"], np.int64)
        self.rest_lin = fing
        self.rest_ang = arm_dofs.astype(np.int64)
        names = {b: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(m.nbody)}
        self.bodies = frozenset(n for n in names.values() if n.startswith(("left_", "right_")))
        hand_bodies = {"gripper_link", "gripper_prop_link", "hand"}
        self.geom_arm = np.full(m.ngeom, NO_ARM, np.int64)
        self.geom_part = np.zeros(m.ngeom, np.int64)
        for g in range(m.ngeom):
            body = names[int(m.geom_bodyid[g])]
            side, _, part = body.partition("_")
            if side not in SIDES:
                continue
            self.geom_arm[g] = SIDES.index(side)
            self.geom_part[g] = (PART_FINGER_L if part == "hand_finger_l" else PART_FINGER_R if part == "hand_finger_r"
                                 else PART_PALM if part in hand_bodies else PART_LINK)

    def prepare(self, scene, object_poses, actions, fps, until_failure=False) -> Execution:
        motion = self.robot.motion(self.task_name, actions, scene.task.keypoints_world(object_poses), fps,
                                   until_failure=until_failure, collides=self.collision_check(scene, object_poses))
        return Execution(motion.poses, motion)

    def collision_check(self, scene, object_poses):
        """rows (k, 12) of both arms' joints -> (k, 2) bool: the arm comes within TRANSIT_CLEARANCE of the table,
        an object at its place at the episode's start, or the other arm (the scene's contact tables; the fingers
        open to the gripper's opening), or its pinch point leaves the task's workspace by more than the arms'
        slack (the physics check allows the workspace margin more). The clearance absorbs what the executed
        transit deviates from the planned one (the servos' lag, the retiming)."""
        import copy

        import mujoco

        if getattr(self, "_check_data", None) is None:
            self._check_model = copy.copy(scene.model)
            self._check_model.geom_margin[self.geom_arm >= 0] = TRANSIT_CLEARANCE
            self._check_data = mujoco.MjData(self._check_model)
        m = self._check_model
        d = self._check_data
        mujoco.mj_resetData(m, d)
        scene.place_objects(d, np.asarray(object_poses, float))
        d.qpos[self.finger_qadr] = (self.spec.stroke - self.spec.opening) / 2  # open as the executor opens them
        kind, arm_of = scene.pair_kind, self.geom_arm
        lo, hi = scene.workspace[0] - self.hand_workspace_slack, scene.workspace[1] + self.hand_workspace_slack

        def collides(rows: np.ndarray) -> np.ndarray:
            out = np.zeros((len(rows), 2), bool)
            for i, q in enumerate(rows):
                d.qpos[self.arm_qadr] = q
                mujoco.mj_kinematics(m, d)
                pinch = d.site_xpos[self.pinch]
                out[i] = ((pinch < lo) | (pinch > hi)).any(axis=1)
                mujoco.mj_collision(m, d)
                for g1, g2 in d.contact.geom[:d.ncon]:
                    if kind[g1, g2]:
                        for g in (g1, g2):
                            if arm_of[g] >= 0:
                                out[i, arm_of[g]] = True
            return out

        return collides

    def plan(self, scene, execution, quat, targets_pos, targets_wxyz, ctrl_per_frame, fps) -> MotionPlan:
        motion = execution.state
        q = motion.q
        n, cpf = len(q), ctrl_per_frame
        tq = np.arange(1, (n - 1) * cpf + 1) / cpf
        q_ctrl = np.stack([np.interp(tq, np.arange(n), q[:, j]) for j in range(q.shape[1])], axis=1) \
            if n > 1 else q[:0]
        # velocity feed-forward: the position actuator's damping acts on the joint's velocity, so a command
        # ahead of the reference by (kv / kp) x its velocity makes the force kp (q_ref - q) + kv (v_ref - v):
        # the servo tracks a moving reference without the lag a plain position command would have
        if n > 1:
            v_ref = np.diff(q, axis=0)[np.minimum((tq - 1e-9).astype(int), n - 2)] * fps
            q_ctrl = q_ctrl + v_ref * LEAD
        events = []
        first = motion.first_failure()
        if first is not None:
            events.append(PlanEvent(first[0], first[2], first[3]))
        return _JointPlan(self.arm_act, q_ctrl, q[0], events, motion.summary())

    def reset(self, d, plan, pose0, width0) -> None:
        d.qpos[self.arm_qadr] = plan.q0
        d.ctrl[self.arm_act] = plan.q0
        for arm in range(2):
            d.qpos[self.finger_qadr[arm]] = (self.spec.stroke - width0[arm]) / 2
            d.ctrl[self.grip_act[arm]] = self.spec.ctrl_for_width(width0[arm])

    def record(self, d, out) -> None:
        import mujoco

        out[:, :3] = d.site_xpos[self.pinch]
        q = np.zeros(4)
        for a in range(2):
            mujoco.mju_mat2Quat(q, d.site_xmat[self.pinch[a]])
            out[a, 3:7] = q[[1, 2, 3, 0]]


__all__ = ["AlohaRobot", "HANDS", "JOINT_NAMES", "BasePose"]
