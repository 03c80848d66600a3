"""What the simulator asks of a robot: the embodiment interface.

A :class:`Robot` is a frozen, hashable description (its fields are its options: which gripper, where
its bases stand). The scene builder (lib/sim/scene.py) adds its MJCF (:meth:`Robot.scene_parts`) to a
task's scene and binds it to the compiled model (:meth:`Robot.bind`: joint, actuator and geom indices);
the executor (lib/sim/executor.py) asks the binding what it executes of an episode
(:meth:`RobotBinding.prepare`: the actions as they are, or an arm's own start, transits and
time-scaling), then for a :class:`MotionPlan` (how each control step drives the robot, and the hard
failures known before any physics, such as an unreachable pose), resets the robot into the plan's
first state and records the actual pinch poses.
The failure checks read the geoms' parts (:data:`PART_FINGER_L` ... :data:`PART_LINK`); the renderer
draws whatever the scene holds; the exports ask for the joint names and the joint trajectory of an
episode as the robot executes it (:meth:`Robot.joint_values` of the binding's :class:`Execution`, arms only).

Every robot drives its fingers the same way (lib/sim/gripper.py, :func:`~demoforge.lib.sim.gripper.finger_drive`):
two slide joints `<hand>_l`, `<hand>_r` coupled symmetric, one force-limited position actuator on
their summed travel, described by a :class:`~demoforge.lib.sim.gripper.GripperSpec` (stroke, force,
speed, the g mapping), so the executor's finger command is the same for every hand.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from demoforge.lib.sim.gripper import GripperSpec

# The part of a robot geom, for the contact bookkeeping (lib/sim/scene.py pair tables, failures.py)
PART_FINGER_L, PART_FINGER_R, PART_PALM, PART_LINK = 0, 1, 2, 3
NO_ARM = -1


def as_index(ids):
    """A slice for contiguous ids (cheaper MjData writes than fancy indexing), else the array."""
    ids = np.asarray(ids)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


@dataclass(frozen=True)
class SceneParts:
    """MJCF fragments a robot adds to a task's scene: the bodies (`worldbody`), `<equality>`,
    `<tendon>`, `<actuator>` and `<contact>` children, `<asset>` children (`asset_xml`, e.g. meshes)
    and the files those name (`assets`: file name -> bytes, handed to MuJoCo's compiler; no path on
    disk enters the XML, so the scene's text and fingerprint do not depend on where demoforge lives)."""
    worldbody: str
    equality: str = ""
    tendon: str = ""
    actuator: str = ""
    contact: str = ""
    asset_xml: str = ""
    assets: Mapping[str, bytes] = field(default_factory=dict)


@dataclass
class Execution:
    """What a robot executes of an episode: (m, 2, 8) actions at the episode's frame rate (the given ones
    for a robot that follows any pose; an arm robot's own start, transits and time-scaling otherwise)
    and the robot's planning state (e.g. its joint trajectory), handed to :meth:`RobotBinding.plan`."""
    actions: np.ndarray
    state: Any = None


@dataclass
class PlanEvent:
    """A hard failure found while planning, before physics: at action frame `frame`."""
    frame: int
    failure: str
    detail: str


class MotionPlan(abc.ABC):
    """How one episode drives a robot: control step k (0 .. K-1, `ctrl_per_frame` per action frame
    after the first) writes its targets into MjData. `events`: hard failures known before physics
    (earliest first); `summary`: per-episode figures for the results table (e.g. the IK residual)."""

    events: list[PlanEvent]
    summary: dict[str, Any]

    @abc.abstractmethod
    def apply(self, d, k: int) -> None:
        """Write control step k's targets (mocap poses, joint position commands) into MjData `d`."""


class RobotBinding(abc.ABC):
    """A robot inside one compiled scene: what the executor and the scene's bookkeeping index.

    Attributes set by the implementation:
      finger_qadr (2, 2)  qpos addresses of each hand's left / right finger slide
      grip_act (2,)       each hand's finger actuator
      geom_arm, geom_part (ngeom,)  the arm (0 left, 1 right; NO_ARM for non-robot geoms) and part of every geom
      bodies              names of the robot's bodies (never a task's extra free body)
      rest_lin, rest_ang  dof addresses whose speed (m/s, rad/s) must be small for the scene to be at rest
    """

    #: m a hand may go beyond the task's workspace (an arm's own ready pose and transits lie outside the box
    #: the demonstrated trajectories are bounded by; objects keep the box)
    hand_workspace_slack: float = 0.0
    finger_qadr: np.ndarray
    grip_act: np.ndarray
    geom_arm: np.ndarray
    geom_part: np.ndarray
    bodies: frozenset
    rest_lin: np.ndarray
    rest_ang: np.ndarray

    def prepare(self, scene, object_poses: np.ndarray, actions: np.ndarray, fps: float,
                until_failure: bool = False) -> Execution:
        """What the robot executes of the episode's (n, 2, 8) actions with the objects at object_poses
        (n_obj, 4, 4); by default the actions as they are. until_failure: the simulation stops at the
        first hard failure, so the robot may stop planning there too."""
        return Execution(actions)

    @abc.abstractmethod
    def plan(self, scene, execution: Execution, quat: np.ndarray, targets_pos: np.ndarray,
             targets_wxyz: np.ndarray, ctrl_per_frame: int, fps: float) -> MotionPlan:
        """The episode's plan for the executed actions (``execution.actions``, (m, 2, 8)). quat: (m, 2, 4)
        unit xyzw; targets_pos, targets_wxyz: the pinch targets interpolated at control rate
        ((m - 1) * ctrl_per_frame, 2, 3 | 4)."""

    @abc.abstractmethod
    def reset(self, d, plan: MotionPlan, pose0: np.ndarray, width0: np.ndarray) -> None:
        """Put the robot into the plan's first state: pinch poses pose0 (2, 7 xyzw), apertures width0 (2,)."""

    @abc.abstractmethod
    def record(self, d, out: np.ndarray) -> None:
        """The actual pinch poses now into out (2, >= 7): x y z qx qy qz qw."""


class Robot(abc.ABC):
    """A robot the simulator can execute (n, 2, 8) gripper actions with (see the module docstring)."""

    name: ClassVar[str]
    #: the joint-space export's names of the 14 (or more) joint values, empty for a robot without joints
    joint_names: ClassVar[tuple[str, ...]] = ()

    @property
    @abc.abstractmethod
    def gripper(self) -> GripperSpec:
        """The hands' finger mechanics (both hands alike)."""

    @property
    @abc.abstractmethod
    def gripper_name(self) -> str:
        """The hand's short name, as the `gripper` column of the results writes it (e.g. `2f140`)."""

    @abc.abstractmethod
    def scene_parts(self, task_name: str) -> SceneParts:
        """The robot's MJCF for a task's scene (a robot may stand differently at each task's table)."""

    @abc.abstractmethod
    def bind(self, model, task_name: str) -> RobotBinding:
        """Index the robot in a compiled scene of `task_name`."""

    def settings(self, task_name: str) -> str:
        """What else decides the robot's motion besides its MJCF (e.g. its IK's speed limits and version),
        as text: part of the scene fingerprint, so cached results go stale when it changes."""
        return ""

    def joint_values(self, execution: Execution) -> np.ndarray:
        """(m, len(joint_names)) joint values of an executed episode (its :meth:`RobotBinding.prepare`), as the
        joint-space export writes them; only for a robot with joints."""
        raise NotImplementedError(f"the {self.name} robot has no joints to export")

    @property
    def label(self) -> str:
        """`grippers`, `aloha` or `aloha+2f140`: the robot and, where it has a choice, its hand."""
        return self.name
