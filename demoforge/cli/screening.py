"""`demoforge screen`: whether a robot's arms can execute each episode of a task database (a sub-app composed
into the root app)."""

from __future__ import annotations

import time
from typing import Optional

import typer

from demoforge.cli.root import current_warehouse, fail, gripper_option, robot_choice
from demoforge.runtime.runners import run_flow

app = typer.Typer()

SCREEN_ROBOT_HELP = ("The robot whose arms are screened: aloha (two ViperX 300 6-DOF arms; the floating grippers "
                     "reach every pose and need no screening).")


@app.command("screen")
def screen_cmd(
    task: str = typer.Option(..., "--task", "-t", help="Task whose episode database to screen."),
    robot: str = typer.Option("aloha", "--robot", help=SCREEN_ROBOT_HELP),
    gripper: Optional[str] = gripper_option(),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); default: the task's first."),
) -> None:
    """Screen every episode of a task database for the robot's arms, without physics.

    Per episode: can both arms follow their windows of the episode with the grasps their planner would
    choose (reach, joint ranges, no joint jumping, the wrist and the fingertips above the table) with
    their forearms apart? The same windows, grasps and rules as the arms' motion planner (`demoforge
    simulate --robot aloha`), for all episodes at once with the ViperX's closed-form inverse kinematics
    (no physics: seconds per thousand episodes on one core). Rows: `episode_screening` (executable, the
    first cause when not, the smallest joint margin); e.g. demoforge sql "SELECT reason, count(*) FROM
    episode_screening WHERE task = 'pouring' GROUP BY reason"."""
    from demoforge.flows.screening import check_robot, screen_task  # lazy: prefect
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.sim.robots import RobotError, available_robots
    from demoforge.lib.task_library import TASK_NAMES

    if task not in TASK_NAMES:
        raise fail(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    if robot not in available_robots():
        raise fail(f"--robot must be one of {', '.join(available_robots())}, got {robot!r}")
    robot, gripper = robot_choice(robot, gripper)
    t0 = time.perf_counter()
    try:
        check_robot(robot, gripper)
        run_flow(screen_task, str(current_warehouse()), task=task, take=take, robot=robot, gripper=gripper)
    except (ValueError, RobotError) as e:
        raise fail(str(e))
    say_screening(task, robot, gripper, time.perf_counter() - t0)


def say_screening(task: str, robot: str, gripper: str, seconds: float | None = None) -> None:
    """One line per database: episodes screened, the share executable, the causes of the others."""
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    t = query("SELECT take, robot, count(*) AS episodes, count(*) FILTER (WHERE executable) AS executable, "
              "string_agg(DISTINCT reason, ', ' ORDER BY reason) FILTER (WHERE NOT executable) AS reasons "
              "FROM episode_screening WHERE task = ? AND gripper = ? AND starts_with(robot, ?) GROUP BY take, robot "
              "ORDER BY take", current_warehouse(), [task, gripper, robot]).to_pylist()
    for r in t:
        share = r["executable"] / max(r["episodes"], 1)
        typer.echo(f"{task}/{r['take']} ({r['robot']}): {r['executable']} of {r['episodes']} episodes executable "
                   f"({share:.1%}); the others: {r['reasons'] or '-'}"
                   + (f"; {seconds:.1f} s" if seconds is not None else ""))
