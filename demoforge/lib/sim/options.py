"""The simulator's options for a robot named by the command line, a flow's parameter or a table row."""

from __future__ import annotations

from .executor import SimOptions
from .robots import RobotSpec, resolve_robot


def sim_options(robot="grippers", gripper: str | None = None) -> SimOptions:
    """The simulator's options for a robot: a demoforge.lib.robot_spec.RobotSpec, its label, or a robot's name
    and hand (an unknown one: RobotError); the embodiment is built once per process (resolve_robot)."""
    return SimOptions(robot=resolve_robot(RobotSpec.of(robot, gripper)))
