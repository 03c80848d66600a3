"""The `grippers` robot: two free-floating Robotiq 2F-140-class grippers, each following its pose through
a soft weld to a mocap target (lib/sim/gripper.py says how they are built). No arm: every pose is
reachable, nothing but the hands can collide. Kept as the reference the arms are compared with."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from demoforge.lib.geometry import xyzw_to_wxyz
from demoforge.lib.sim.gripper import GripperSpec, gripper_sections

from .base import NO_ARM, as_index, PART_FINGER_L, PART_FINGER_R, PART_PALM, MotionPlan, Robot, RobotBinding, SceneParts


@dataclass(frozen=True)
class GrippersRobot(Robot):
    spec: GripperSpec = field(default_factory=GripperSpec)

    name: ClassVar[str] = "grippers"

    @property
    def gripper(self) -> GripperSpec:
        return self.spec

    @property
    def gripper_name(self) -> str:
        return "2f140"

    def scene_parts(self, task_name: str) -> SceneParts:
        sec = gripper_sections(self.spec)
        return SceneParts(worldbody=sec["worldbody"], equality=sec["equality"], tendon=sec["tendon"],
                          actuator=sec["actuator"], contact=sec["contact"])

    def bind(self, model, task_name: str) -> "GrippersBinding":
        return GrippersBinding(model, self.spec)


class _MocapPlan(MotionPlan):
    """Each control step moves the mocap targets to the interpolated pinch poses."""

    def __init__(self, mocap, targets_pos, targets_wxyz):
        self.mocap, self.pos, self.wxyz = mocap, targets_pos, targets_wxyz
        self.events, self.summary = [], {}

    def apply(self, d, k: int) -> None:
        d.mocap_pos[self.mocap] = self.pos[k]
        d.mocap_quat[self.mocap] = self.wxyz[k]


class GrippersBinding(RobotBinding):
    def __init__(self, m, spec: GripperSpec):
        import mujoco

        self.spec = spec

        def bid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)

        def jid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

        self.base_body = np.array([bid(f"g{a}_base") for a in range(2)])
        self.base_qadr = np.array([m.jnt_qposadr[m.body_jntadr[b]] for b in self.base_body])
        base_vadr = np.array([m.jnt_dofadr[m.body_jntadr[b]] for b in self.base_body])
        self.mocap = as_index([m.body_mocapid[bid(f"g{a}_target")] for a in range(2)])
        self.mocap_ids = np.array([m.body_mocapid[bid(f"g{a}_target")] for a in range(2)])
        self.finger_qadr = np.array([[m.jnt_qposadr[jid(f"g{a}_{s}")] for s in "lr"] for a in range(2)])
        self.grip_act = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"g{a}_grip") for a in range(2)])
        self.bodies = frozenset(f"g{a}_{b}" for a in range(2) for b in ("base", "target", "finger_l", "finger_r"))
        fing = np.array([m.jnt_dofadr[jid(f"g{a}_{s}")] for a in range(2) for s in "lr"], np.int64)
        self.rest_lin = np.concatenate([(base_vadr[:, None] + np.arange(3)).ravel(), fing]).astype(np.int64)
        self.rest_ang = (base_vadr[:, None] + np.arange(3, 6)).ravel().astype(np.int64)
        self.geom_arm = np.full(m.ngeom, NO_ARM, np.int64)
        self.geom_part = np.zeros(m.ngeom, np.int64)
        for g in range(m.ngeom):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
            if name.startswith("g0_") or name.startswith("g1_"):
                self.geom_arm[g] = int(name[1])
                self.geom_part[g] = PART_FINGER_L if name.endswith("_l") else PART_FINGER_R if name.endswith("_r") \
                    else PART_PALM

    def plan(self, scene, execution, quat, targets_pos, targets_wxyz, ctrl_per_frame, fps) -> MotionPlan:
        return _MocapPlan(self.mocap, targets_pos, targets_wxyz)

    def reset(self, d, plan, pose0, width0) -> None:
        for arm in range(2):
            a = self.base_qadr[arm]
            d.qpos[a:a + 3] = pose0[arm, :3]
            d.qpos[a + 3:a + 7] = xyzw_to_wxyz(pose0[arm, 3:7])
            d.mocap_pos[self.mocap_ids[arm]] = pose0[arm, :3]
            d.mocap_quat[self.mocap_ids[arm]] = xyzw_to_wxyz(pose0[arm, 3:7])
            d.qpos[self.finger_qadr[arm]] = (self.spec.stroke - width0[arm]) / 2
            d.ctrl[self.grip_act[arm]] = self.spec.ctrl_for_width(width0[arm])

    def record(self, d, out) -> None:
        out[:, :3] = d.xpos[self.base_body]
        out[:, 3:7] = d.xquat[self.base_body][:, [1, 2, 3, 0]]
