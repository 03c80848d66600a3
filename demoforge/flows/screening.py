"""Flow: screen a task's episode database for a robot's arms (tasks/screening.py -> `episode_screening`)."""

from __future__ import annotations

from prefect import flow

from demoforge.lib.sim.robots import get_robot
from demoforge.lib.task_library import TASK_NAMES
from demoforge.schemas.catalog import query
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.screening import code_files, database_files, screen_database


def check_robot(robot: str, gripper: str | None):
    """The robot by name and hand, if it has arms the screening knows (an unknown one: RobotError; the
    floating grippers: ValueError)."""
    r = get_robot(robot, gripper)
    if not hasattr(r, "retargeting"):
        raise ValueError(f"--robot {robot}: the screening checks arms (reach, joint ranges, grasps); the floating "
                         "grippers reach every pose. Use --robot aloha")
    return r


def episode_database(warehouse: str, task: str, take: str | None) -> str:
    """The take whose database to screen (default: the task's first); ValueError naming the choices."""
    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    takes = query("SELECT DISTINCT take FROM episodes WHERE task = ? ORDER BY take", warehouse, [task]).column(0).to_pylist()
    if take is None and takes:
        take = takes[0]
    if take is None or take not in takes:
        raise ValueError(f"no episode database for {task!r}{' from take ' + take if take else ''}: "
                         "run `demoforge augment` first")
    return take


@flow(name="screen-episodes")
def screen_task(warehouse: str, task: str, take: str | None = None, robot: str = "aloha",
                gripper: str | None = None) -> Manifest:
    """Screen every episode of the task's database (take; default: the task's first) for the robot's arms:
    one cached stage, keyed by the database's files and the planner's code."""
    arms = check_robot(robot, gripper)
    take = episode_database(warehouse, task, take)
    return run_stage(screen_database, warehouse, task=task, take=take, warehouse=warehouse,
                     source=database_files(warehouse, task, take), code=code_files(), robot=arms.name,
                     gripper=arms.gripper_name)
