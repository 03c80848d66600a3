"""Which robot, by name: the robots' registry (name -> its class, loaded lazily, and the hands it can
carry) and :class:`RobotSpec`, the robot and hand a run asks for, parsed and checked once.

    spec = RobotSpec.parse("aloha+2f140")            # the tables' label syntax
    spec == RobotSpec.from_options("aloha", "2f140")  # the CLI's --robot aloha --gripper 2f140
    spec.label, spec.robot, spec.gripper             # "aloha+2f140", "aloha", "2f140"
    demoforge.lib.sim.robots.resolve_robot(spec)     # the embodiment, built once per process

Here, not in lib/sim/robots: the command line and the main job's configuration check robot names
without importing numpy, MuJoCo or the robots' models. An unknown robot or a hand it cannot carry is a
:class:`RobotError` (a user error: one line listing the choices).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from demoforge.lib.errors import UnknownNameError
from demoforge.lib.registry import Registry

__all__ = ["DEFAULT_ROBOT", "ROBOTS", "RobotError", "RobotSpec", "available_robots", "gripper_choices",
           "register_robot", "robot_labels"]

DEFAULT_ROBOT = "grippers"


class RobotError(UnknownNameError):
    """An unknown robot or a hand it cannot carry; the message lists the choices."""


#: name -> the robot's class (or a factory) taking `hand=` when it carries more than one hand
ROBOTS: Registry[Callable[..., Any]] = Registry("robot", {
    "grippers": "demoforge.lib.sim.robots.grippers:GrippersRobot",
    "aloha": "demoforge.lib.sim.robots.aloha:AlohaRobot",
}, error=RobotError)
# name -> the hands it can carry, its own (the default) first
_HANDS: dict[str, tuple[str, ...]] = {"grippers": ("2f140",), "aloha": ("aloha", "2f140")}


def register_robot(name: str, factory: Callable[..., Any] | str, grippers: tuple[str, ...]) -> None:
    """Register a robot: a callable taking `hand=` (none for a robot with one hand), or a lazy
    "module:attribute" string, and the hands it carries (its own first)."""
    if not grippers:
        raise ValueError(f"robot {name!r}: name at least one hand it carries")
    ROBOTS.register(name, factory)
    _HANDS[name] = tuple(grippers)


def available_robots() -> tuple[str, ...]:
    return ROBOTS.names()


def gripper_choices(name: str) -> tuple[str, ...]:
    """The hands robot `name` can carry, its own first (an unknown robot: RobotError)."""
    return _HANDS[ROBOTS.check(name)]


def robot_labels() -> tuple[str, ...]:
    """Every robot with every hand it carries, as labels: `grippers`, `aloha`, `aloha+2f140`."""
    return tuple(RobotSpec(name, hand).label for name in available_robots() for hand in gripper_choices(name))


@dataclass(frozen=True)
class RobotSpec:
    """A robot and its hand, checked when made: `robot` is a registered robot, `gripper` one of the hands
    it carries (None: its own; stored as that hand's name, so equal requests are equal objects).

    :attr:`label` is what the tables write in their `robot` column where a robot's hand is part of its
    name (`grippers`, `aloha`, `aloha+2f140`: the hand only where it is not the robot's own), and
    :meth:`parse` reads it back. `robot` and `gripper` are the `sim_results` columns of the same name."""

    robot: str = DEFAULT_ROBOT
    gripper: str | None = None

    def __post_init__(self) -> None:
        hands = gripper_choices(self.robot)
        gripper = self.gripper or hands[0]
        if gripper not in hands:
            raise RobotError(f"the {self.robot} robot carries {' or '.join(hands)}, not {gripper!r}",
                             kind=f"hand of the {self.robot} robot", name=gripper, choices=hands)
        object.__setattr__(self, "gripper", gripper)

    @classmethod
    def parse(cls, label: str) -> "RobotSpec":
        """`aloha+2f140` -> RobotSpec("aloha", "2f140"); `aloha` -> RobotSpec("aloha"): its own hand."""
        name, _, hand = str(label).strip().partition("+")
        return cls(name, hand or None)

    @classmethod
    def from_options(cls, robot: str = DEFAULT_ROBOT, gripper: str | None = None) -> "RobotSpec":
        """The CLI's `--robot aloha --gripper 2f140` (no --gripper: the robot's own hand)."""
        return cls(robot, gripper or None)

    @classmethod
    def of(cls, robot: "RobotSpec | str" = DEFAULT_ROBOT, gripper: str | None = None) -> "RobotSpec":
        """A spec from what a flow's caller gives: a RobotSpec, a label (`aloha+2f140`), or a robot name
        with a hand (the CLI's options, a deployment's JSON parameters)."""
        if isinstance(robot, RobotSpec):
            if gripper is not None and gripper != robot.gripper:
                raise RobotError(f"robot {robot.label} was given with another hand, {gripper!r}")
            return robot
        if "+" in str(robot):
            spec = cls.parse(robot)
            return cls.of(spec, gripper)
        return cls.from_options(robot, gripper)

    @property
    def hands(self) -> tuple[str, ...]:
        return gripper_choices(self.robot)

    @property
    def label(self) -> str:
        """`grippers`, `aloha` or `aloha+2f140`: the robot and, where it is not its own, its hand."""
        return self.robot if self.gripper == self.hands[0] else f"{self.robot}+{self.gripper}"

    def __str__(self) -> str:
        return self.label
