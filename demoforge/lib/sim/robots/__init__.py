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
fields are its options) and ``register_robot("mine", "module:Class", grippers=("hand", ...))``.
"""

from __future__ import annotations

import importlib
from typing import Callable

from demoforge.lib.errors import UserError

from .base import (NO_ARM, PART_FINGER_L, PART_FINGER_R, PART_LINK, PART_PALM, Execution, MotionPlan, PlanEvent,
                   Robot, RobotBinding, SceneParts)

DEFAULT_ROBOT = "grippers"

# name -> (factory or lazy "module:attribute", the hands it can carry; the first is its default)
_REGISTRY: dict[str, tuple[Callable[..., Robot] | str, tuple[str, ...]]] = {
    "grippers": ("demoforge.lib.sim.robots.grippers:GrippersRobot", ("2f140",)),
    "aloha": ("demoforge.lib.sim.robots.aloha:AlohaRobot", ("aloha", "2f140")),
}


class RobotError(UserError):
    """An unknown robot or a hand it cannot carry; the message lists the choices."""


def register_robot(name: str, factory: Callable[..., Robot] | str, grippers: tuple[str, ...]) -> None:
    """Register a robot: a callable taking `gripper=` (or a lazy "module:attribute" string) and its hands."""
    _REGISTRY[name] = (factory, tuple(grippers))


def available_robots() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def gripper_choices(name: str) -> tuple[str, ...]:
    if name not in _REGISTRY:
        raise RobotError(f"unknown robot {name!r}; choose one of: {', '.join(available_robots())}")
    return _REGISTRY[name][1]


def get_robot(name: str = DEFAULT_ROBOT, gripper: str | None = None) -> Robot:
    """The robot `name` with hand `gripper` (default: the robot's own)."""
    choices = gripper_choices(name)
    gripper = gripper or choices[0]
    if gripper not in choices:
        raise RobotError(f"the {name} robot carries {' or '.join(choices)}, not {gripper!r} (--gripper)")
    factory = _REGISTRY[name][0]
    if isinstance(factory, str):
        mod, attr = factory.split(":")
        factory = getattr(importlib.import_module(mod), attr)
    return factory() if len(choices) == 1 else factory(hand=gripper)


__all__ = ["DEFAULT_ROBOT", "Execution", "NO_ARM", "PART_FINGER_L", "PART_FINGER_R", "PART_LINK", "PART_PALM",
           "MotionPlan", "PlanEvent", "Robot", "RobotBinding", "RobotError", "SceneParts", "available_robots", "get_robot",
           "gripper_choices", "register_robot"]
