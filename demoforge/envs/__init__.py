"""Every task of the library, with each robot, as a Gymnasium environment (registered on import).

    import gymnasium, demoforge.envs
    env = gymnasium.make("demoforge/pouring-aloha2f140-v0")
    obs, info = env.reset(seed=0, options={"protocol": "thesis"})
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Ids: ``demoforge/<task>-<robot>-v0`` for every task of demoforge.lib.task_library.TASK_NAMES and every
robot key of :data:`ROBOTS`, which map to the robot checks' ``--robot`` / ``--gripper`` (Gymnasium ids
cannot hold the ``+`` of the robot label ``aloha+2f140``):

========== ================================ ===================================================
key        ``--robot ... --gripper ...``    action and ``observation.state``
========== ================================ ===================================================
aloha      ``aloha --gripper aloha``        14 joints: per arm 6 (rad) + gripper opening (0..1)
aloha2f140 ``aloha --gripper 2f140``        the same 14, the Robotiq 2F-140 on the wrists
grippers   ``grippers`` (2F-140)            16 pose values: per arm x y z qx qy qz qw g
========== ================================ ===================================================

This module imports only Gymnasium and two pure-Python name tables: the environment
(demoforge/envs/robot_env.py: MuJoCo, the simulator of demoforge.lib.sim) is imported by
``gymnasium.make``. The tasks are demoforge.lib.task_names.TASK_NAMES and the robot keys come from the
robots' registry (demoforge.lib.robot_spec.robot_labels, the ``+`` dropped), so a registered robot gets its
environments without a second list.
"""

from __future__ import annotations

import gymnasium

from demoforge.lib.robot_spec import RobotSpec, robot_labels
from demoforge.lib.task_names import TASK_NAMES

TASKS = TASK_NAMES
#: robot key of an id -> (robot, gripper) as demoforge.lib.sim.robots.get_robot takes them
ROBOTS = {label.replace("+", ""): (spec.robot, spec.gripper)
          for label, spec in ((label, RobotSpec.parse(label)) for label in robot_labels())}
ENTRY_POINT = "demoforge.envs.robot_env:DemoforgeEnv"


def env_id(task: str, robot: str) -> str:
    """The Gymnasium id of a task with a robot key of ROBOTS, e.g. ``demoforge/pouring-aloha2f140-v0``."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {', '.join(TASKS)}")
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot key {robot!r}; choose one of {', '.join(ROBOTS)}")
    return f"demoforge/{task}-{robot}-v0"


def register_envs() -> list[str]:
    """Register every (task, robot) id not registered yet; returns all the ids. No step limit wrapper: the
    environment ends its episodes itself (max_steps), after the settle phase and the verdict."""
    ids = []
    for task in TASKS:
        for key, (robot, gripper) in ROBOTS.items():
            name = env_id(task, key)
            if name not in gymnasium.registry:
                gymnasium.register(id=name, entry_point=ENTRY_POINT,
                                   kwargs={"task": task, "robot": robot, "gripper": gripper})
            ids.append(name)
    return ids


ENV_IDS = tuple(register_envs())

__all__ = ["ENV_IDS", "ROBOTS", "TASKS", "env_id", "register_envs"]
