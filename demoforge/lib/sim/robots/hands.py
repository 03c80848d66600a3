"""The demonstrator's hands: the embodiment the task library's scripted demonstrations are replayed with.

Two mocap bodies `pinch_0`, `pinch_1` (a small sphere each, without contacts) follow the demonstration's
pinch frames, and a hand holds an object by a weld to it (`hold_<arm>_<object>`, one per hand and task
object, inactive until the demonstration grasps): no fingers, no friction, so a scripted take's replay
checks the script and the task's predicate, not a gripper. Internal: :func:`demoforge.lib.sim.replay.replay`
drives it through the simulator's frame loop (loop.py); it is not one of the robots a run may name
(lib/robot_spec.py), nor in their registry.

What each frame does is the task library's replay as it has always been, so its verdicts and object
poses stay what they were: the targets of control step c of a frame blend the frame's two pinch poses
linearly by c / ctrl_per_frame (the positions, and the hemisphere-aligned quaternions, normalised; not the
executor's slerp, which the plan is offered and ignores), and before the first control step of frame t the
welds follow the held objects of frame t (``Execution.state``: the demonstration's (n, 2) held object per
arm, -1 none); a weld switched on holds the object at its pose relative to the hand at that moment.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from demoforge.lib.sim.gripper import GripperSpec
from demoforge.lib.task_library import get_task

from .base import NO_ARM, Execution, MotionPlan, Robot, RobotBinding, SceneParts


@dataclass(frozen=True)
class DemoHands(Robot):
    """The demonstrator's two hands (see the module docstring)."""

    name: ClassVar[str] = "demo_hands"

    @property
    def gripper(self) -> GripperSpec:
        return GripperSpec()  # no fingers: only read for the records' (unused) finger width

    @property
    def gripper_name(self) -> str:
        return ""

    def scene_parts(self, task_name: str) -> SceneParts:
        mocap = "\n".join(
            f'<body name="pinch_{a}" mocap="true"><geom type="sphere" size="0.008" '
            f'rgba="{"0.2 0.2 1" if a == 0 else "1 0.2 0.2"} 0.5" contype="0" conaffinity="0" mass="0"/></body>'
            for a in range(2))
        welds = "\n".join(
            f'<weld name="hold_{a}_{o}" body1="pinch_{a}" body2="{o}" active="false" solref="0.01 1"/>'
            for a in range(2) for o in get_task(task_name).object_names)
        return SceneParts(worldbody=mocap, equality=welds)

    def bind(self, model, task_name: str) -> "DemoHandsBinding":
        return DemoHandsBinding(model, get_task(task_name).object_names)


def blend(pos: np.ndarray, wxyz: np.ndarray, t0: int, t1: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """The hands' targets a fraction alpha from frame t0 to t1: (2, 3) positions, (2, 4) unit wxyz."""
    p = np.empty((2, 3))
    q = np.empty((2, 4))
    for a in range(2):
        p[a] = (1 - alpha) * pos[t0, a] + alpha * pos[t1, a]
        q0, q1 = wxyz[t0, a], wxyz[t1, a]
        if np.dot(q0, q1) < 0:
            q1 = -q1
        qa = (1 - alpha) * q0 + alpha * q1
        q[a] = qa / np.linalg.norm(qa)
    return p, q


class HoldPlan(MotionPlan):
    """The hands' targets at control rate and the welds' switching by the held objects (module docstring)."""

    def __init__(self, binding: "DemoHandsBinding", model, actions: np.ndarray, held: np.ndarray, cpf: int):
        self.b, self.model, self.cpf = binding, model, cpf
        self.held = np.asarray(held, int)
        if self.held.shape != actions.shape[:2]:
            raise ValueError(f"held objects {self.held.shape} do not match the actions {actions.shape[:2]}")
        pos, wxyz = actions[..., :3], actions[..., [6, 3, 4, 5]]  # MuJoCo's scalar-first order
        n = len(actions)
        self.pos0, self.wxyz0 = blend(pos, wxyz, 0, 0, 0.0)
        self.pos = np.empty(((n - 1) * cpf, 2, 3))
        self.wxyz = np.empty(((n - 1) * cpf, 2, 4))
        for t in range(1, n):
            for c in range(1, cpf + 1):
                k = (t - 1) * cpf + c - 1
                self.pos[k], self.wxyz[k] = blend(pos, wxyz, t - 1, t, c / cpf)
        self.prev = [-1, -1]  # the object each hand's weld holds now
        self.started = False
        self.events, self.summary = [], {}

    def start(self, d) -> None:
        """Weld the objects held at frame 0 to their hands (once, after the pre-roll)."""
        if not self.started:
            self.started = True
            self.follow(d, 0)

    def follow(self, d, t: int) -> None:
        """Switch the welds to the objects held at frame t."""
        for a in range(2):
            k = int(self.held[t, a])
            if k != self.prev[a]:
                if self.prev[a] >= 0:
                    d.eq_active[self.b.eq[a, self.prev[a]]] = 0
                if k >= 0:
                    self._weld(d, a, k)
                self.prev[a] = k

    def _weld(self, d, arm: int, obj: int) -> None:
        """Weld object obj to hand arm at their pose relative to each other now."""
        eq_id, mocap_id, body_id = self.b.eq[arm, obj], self.b.mocap_ids[arm], self.b.obj_body[obj]
        pm = d.mocap_pos[mocap_id]
        Rm = Rotation.from_quat(d.mocap_quat[mocap_id][[1, 2, 3, 0]])
        Rb = Rotation.from_matrix(d.xmat[body_id].reshape(3, 3))
        rel_p = Rm.inv().apply(d.xpos[body_id] - pm)
        q = (Rm.inv() * Rb).as_quat()
        self.model.eq_data[eq_id, 3:6] = rel_p
        self.model.eq_data[eq_id, 6:10] = [q[3], q[0], q[1], q[2]]
        d.eq_active[eq_id] = 1

    def apply(self, d, k: int) -> None:
        if k % self.cpf == 0:  # the first control step of frame t: the welds follow frame t's held objects
            self.start(d)
            self.follow(d, k // self.cpf + 1)
        d.mocap_pos[self.b.mocap] = self.pos[k]
        d.mocap_quat[self.b.mocap] = self.wxyz[k]


class DemoHandsBinding(RobotBinding):
    def __init__(self, m, object_names: tuple[str, ...]):
        import mujoco

        def bid(name):
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)

        self.mocap_ids = np.array([m.body_mocapid[bid(f"pinch_{a}")] for a in range(2)])
        self.mocap = self.mocap_ids.tolist()
        self.obj_body = np.array([bid(n) for n in object_names])
        self.eq = np.array([[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, f"hold_{a}_{o}") for o in object_names]
                            for a in range(2)])
        self.finger_qadr = np.zeros((2, 0), np.int64)  # no fingers, no finger actuators
        self.grip_act = np.zeros(0, np.int64)
        self.geom_arm = np.full(m.ngeom, NO_ARM, np.int64)  # the spheres touch nothing
        self.geom_part = np.zeros(m.ngeom, np.int64)
        self.bodies = frozenset(f"pinch_{a}" for a in range(2))
        self.rest_lin = self.rest_ang = np.zeros(0, np.int64)

    def plan(self, scene, execution: Execution, quat, targets_pos, targets_wxyz, ctrl_per_frame, fps) -> HoldPlan:
        held = execution.state if execution.state is not None else np.full(execution.actions.shape[:2], -1)
        return HoldPlan(self, scene.model, execution.actions, held, ctrl_per_frame)

    def reset(self, d, plan, pose0, width0) -> None:
        d.mocap_pos[self.mocap] = plan.pos0  # the plan's frame 0, as its blend writes it
        d.mocap_quat[self.mocap] = plan.wxyz0

    def record(self, d, out) -> None:
        out[:, :3] = d.mocap_pos[self.mocap]
        out[:, 3:7] = d.mocap_quat[self.mocap][:, [1, 2, 3, 0]]
