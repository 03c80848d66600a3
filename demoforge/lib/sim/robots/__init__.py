"""The robots the simulator executes episodes with: the embodiment interface and its registry.

    from demoforge.lib.sim.robots import get_robot
    robot = get_robot("aloha", gripper="2f140")       # or get_robot("grippers")
    execute(task, object_poses, actions, options=SimOptions(robot=robot))

Robots (`available_robots()`; each with the hands it can carry, `gripper_choices(name)`):

* `grippers`: two free-floating Robotiq 2F-140-class grippers welded to mocap targets (the reference:
  every pose is reachable);
* `aloha`: two ViperX 300 6-DOF arms (gym-aloha 0.1.5's model, lib/sim/robots/aloha/assets) driven by
  joint position actuators from inverse kinematics (mink), with ALOHA's own parallel fingers
  (`aloha`, 69 mm between the pads) or the 2F-140 (`2f140`) on the wrist.

Adding a robot: subclass :class:`~demoforge.lib.sim.robots.base.Robot` (a frozen dataclass: its
fields are its options) and ``register_robot("mine", "module:Class", grippers=("hand", ...))``. The
registry and :class:`~demoforge.lib.robot_spec.RobotSpec` (the robot and hand a run asks for, checked
once) live in demoforge.lib.robot_spec, light enough for the command line; they are re-exported here.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

from demoforge.lib.robot_spec import (DEFAULT_ROBOT, ROBOTS, RobotError, RobotSpec, available_robots, gripper_choices,
                                      register_robot, robot_labels)

from .base import (NO_ARM, PART_FINGER_L, PART_FINGER_R, PART_LINK, PART_PALM, Execution, MotionPlan, PlanEvent,
                   Robot, RobotBinding, SceneParts)


def resolve_robot(spec: RobotSpec | str) -> Robot:
    """The embodiment of `spec` (a RobotSpec or its label), built once per process: every stage, flow and
    worker of a process shares the same frozen Robot."""
    spec = RobotSpec.of(spec)
    return _build(ROBOTS.get(spec.robot), spec.gripper if len(spec.hands) > 1 else None)


@functools.cache
def _build(factory: Callable[..., Any], hand: str | None) -> Robot:
    return factory() if hand is None else factory(hand=hand)


def get_robot(name: RobotSpec | str = DEFAULT_ROBOT, gripper: str | None = None) -> Robot:
    """The robot `name` with hand `gripper` (default: the robot's own), or of a RobotSpec or its label:
    resolve_robot of their RobotSpec."""
    return resolve_robot(RobotSpec.of(name, gripper))


__all__ = ["DEFAULT_ROBOT", "Execution", "NO_ARM", "PART_FINGER_L", "PART_FINGER_R", "PART_LINK", "PART_PALM",
           "MotionPlan", "PlanEvent", "ROBOTS", "Robot", "RobotBinding", "RobotError", "RobotSpec", "SceneParts",
           "available_robots", "get_robot", "gripper_choices", "register_robot", "resolve_robot", "robot_labels"]
