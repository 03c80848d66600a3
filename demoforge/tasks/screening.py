"""Prefect task of the arms' screening: a task database's episodes (`episodes`, `episode_steps`) -> whether the
robot's arms can execute each, kinematically (demoforge.lib.sim.robots.aloha.screening) -> `episode_screening`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pyarrow as pa

import demoforge.schemas.screening  # noqa: F401  (registers episode_screening)
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.screening import SCREEN_VERSION, screen_episodes
from demoforge.schemas.catalog import query
from demoforge.schemas.core import read_table, table_files, write_table
from demoforge.tasks.common import Manifest, stage_task

SCREENING_VERSION = f"1/{SCREEN_VERSION}"


def database_files(warehouse: str, task: str, take: str) -> list[Path]:
    """The episode database's files (their content keys the stage's cache)."""
    return [*table_files("episodes", warehouse, task=task, take=take),
            *table_files("episode_steps", warehouse, task=task, take=take)]


def code_files() -> list[Path]:
    """The sources the verdicts depend on (the arms' model and planner, the segmentation, the task library,
    the geometry): their content keys the stage's cache, so a planner change screens again."""
    lib = Path(__file__).resolve().parents[1] / "lib"
    robots = lib / "sim" / "robots"
    return sorted([*(robots / "aloha").glob("*.py"), robots / "arm_motion.py", robots / "retarget.py",
                   lib / "trajectories" / "segmentation.py", lib / "trajectories" / "keyframes.py",
                   *(lib / "task_library").glob("*.py"), *(lib / "geometry").glob("*.py")])


def database_arrays(warehouse: str, task: str, take: str) -> tuple[np.ndarray, ...]:
    """(episode ids (E,), actions (E, n_max, 2, 8) each padded with its last step, lengths (E,), object keypoints
    at the start (E, K, 3)) of a take's database, read column-wise (no Python object per step)."""
    ep = read_table("episodes", warehouse, columns=["episode_id", "object_keypoints", "length"], task=task, take=take)
    if ep.num_rows == 0:
        raise ValueError(f"no episode database for {task!r} from take {take!r}: run `demoforge augment` first")
    ep = ep.sort_by("episode_id")
    ids = ep.column("episode_id").to_numpy()
    lengths = ep.column("length").to_numpy().astype(int)
    kp = ep.column("object_keypoints").combine_chunks().flatten().flatten().to_numpy().reshape(len(ids), -1, 3)
    st = read_table("episode_steps", warehouse, columns=["episode_id", "step", "action"], task=task, take=take)
    act = st.column("action").combine_chunks().flatten().flatten().to_numpy().reshape(-1, 2, 8)
    row = np.searchsorted(ids, st.column("episode_id").to_numpy())
    step = st.column("step").to_numpy()
    actions = np.zeros((len(ids), int(lengths.max()), 2, 8))
    actions[row, step] = act
    pad = np.arange(actions.shape[1])[None] >= lengths[:, None]  # padded with each episode's last step
    actions[pad] = np.repeat(actions[np.arange(len(ids)), lengths - 1], actions.shape[1] - lengths, axis=0)
    return ids, actions, lengths, kp.astype(float)


def screening_rows(task: str, take: str, robot, ids: np.ndarray, s) -> pa.Table:
    """The `episode_screening` rows of a Screening (demoforge.lib.sim.robots.aloha.screening) of episodes ids."""
    n = len(ids)

    def turn(a: int) -> pa.Array:
        v = s.turn[:, a]
        return pa.array(v, pa.float64(), mask=~np.isfinite(v))

    return pa.table({
        "task": pa.array([task] * n), "take": pa.array([take] * n), "episode_id": pa.array(ids, pa.int64()),
        "robot": pa.array([robot.label] * n), "gripper": pa.array([robot.gripper_name] * n),
        "executable": pa.array(s.executable), "reason": pa.array(s.reason.astype(str)),
        "min_margin_rad": pa.array(s.min_margin_rad, pa.float64(), mask=~np.isfinite(s.min_margin_rad)),
        "turn_left_rad": turn(0), "turn_right_rad": turn(1), "screen_version": pa.array([SCREEN_VERSION] * n),
    })


def _logger():
    """The run's logger inside a Prefect run, this module's outside one (a direct call of the function)."""
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:  # noqa: BLE001  (prefect's MissingContextError)
        import logging

        return logging.getLogger(__name__)


@stage_task(name="screen_episodes", version=SCREENING_VERSION)
def screen_database(task: str, take: str, warehouse: str, source: list[Path], code: list[Path],
                    robot: str = "aloha", gripper: str | None = None) -> Manifest:
    """Screen every episode of the take's database for the robot's arms and write its `episode_screening` rows.
    `source` (database_files) and `code` (code_files) only key the cache."""
    arms = get_robot(robot, gripper)
    t0 = time.perf_counter()
    ids, actions, lengths, kp = database_arrays(warehouse, task, take)
    t1 = time.perf_counter()
    arms.retargeting(task)  # the task's closed form and retargeting, built once (not part of the screening)
    t2 = time.perf_counter()
    s = screen_episodes(arms, task, actions, lengths, kp)
    t3 = time.perf_counter()
    _logger().info("%s/%s: %d episodes screened for %s in %.2f s (read %.2f s, set-up %.2f s): %d executable",
                          task, take, len(ids), arms.label, t3 - t2, t1 - t0, t2 - t1, int(s.executable.sum()))
    written = write_table("episode_screening", screening_rows(task, take, arms, ids, s), warehouse)
    return Manifest.from_written("episode_screening", written)


def screened_ids(warehouse: str, task: str, take: str, robot_label: str) -> np.ndarray:
    """The episodes of task/take that the arm robot's screening (`episode_screening`) lets through; ValueError
    naming the command when the database is not screened for it."""
    t = query("SELECT episode_id, executable FROM episode_screening WHERE task = ? AND take = ? AND robot = ?",
              warehouse, [task, take, robot_label])
    if t.num_rows == 0:
        raise ValueError(f"{task}/{take} is not screened for {robot_label}: run `demoforge screen --task {task} "
                         f"--take {take} --robot {robot_label.replace('+', ' --gripper ')}`")
    ok = np.asarray(t.column("executable").to_numpy(zero_copy_only=False))
    return np.asarray(t.column("episode_id").to_numpy())[ok]


def screened_pairs(warehouse: str, task: str, robot_label: str, take: str | None = None) -> set | None:
    """(take, episode_id) of the episodes an arm robot's screening lets through, over the task's databases (or
    `take`'s); None when they are not screened for it."""
    rows = query("SELECT take, episode_id, executable FROM episode_screening WHERE task = ? AND robot = ? "
                 "AND (? IS NULL OR take = ?)", warehouse, [task, robot_label, take, take]).to_pylist()
    return {(r["take"], int(r["episode_id"])) for r in rows if r["executable"]} if rows else None
