"""Flows of the closed-loop policy: train it on a task's screened-in episodes in an arm robot's joint space,
roll it out on held-out scenes in the task's Gymnasium environment, and the data-scaling table (success
against the number of generated episodes trained on, beside the LLM-free baselines on the same scenes)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.flows.policy import _resolve_take
from demoforge.flows.screening import check_robot
from demoforge.lib.robot_spec import RobotSpec
from demoforge.schemas.core import WrittenFile, file_sha256, read_table, table_files
from demoforge.tasks.closed_loop import BASELINES, OPEN_LOOP, closed_loop_train, closed_loop_trials
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.policy import database_inputs, policy_train
from demoforge.tasks.screening import code_files, database_files, screen_database

DEFAULT_SIZES = (1, 10, 100, 1000)
OPEN_LOOP_EPOCHS, OPEN_LOOP_WAYPOINTS = 6, 40  # the open-loop policy as `make evaluate` trains it


def _arms(robot: RobotSpec | str, gripper: str | None):
    """The arm robot of a RobotSpec, a label or a robot's name and hand (a given spec keeps its own hand)."""
    spec = robot if isinstance(robot, RobotSpec) else RobotSpec.of(robot, gripper)
    return check_robot(spec.robot, spec.gripper)


def _screening(warehouse: str, task: str, take: str, arms) -> Manifest:
    return run_stage(screen_database, warehouse, task=task, take=take, warehouse=warehouse,
                     source=database_files(warehouse, task, take), code=code_files(), robot=arms.name,
                     gripper=arms.gripper_name)


@flow(name="train-closed-loop-policy")
def train_closed_loop(warehouse: str, task: str = "pouring", take: str | None = None, episodes: int = 100,
                      seed: int = 0, steps: int = 3000, robot: RobotSpec | str = "aloha",
                      gripper: str | None = "2f140", threads: int = 1) -> Manifest:
    """Train the closed-loop chunk policy on `episodes` episodes of the task's database (the original
    demonstration and episodes its screening for the arms lets through), in the arms' joint space."""
    if episodes < 1 or steps < 1 or threads < 1:
        raise ValueError("episodes, steps and threads must be at least 1")
    arms = _arms(robot, gripper)
    take = _resolve_take(warehouse, task, take)
    screening = _screening(warehouse, task, take, arms)
    m = run_stage(closed_loop_train, warehouse, task=task, take=take, warehouse=warehouse, robot=arms.name,
                  gripper=arms.gripper_name, n_episodes=episodes, screening=screening,
                  database=database_inputs(warehouse, task, take), seed=seed, steps=steps, threads=threads)
    get_run_logger().info("closed-loop policy of %s/%s (%s, %d episodes): %s", task, take, arms.label, episodes, m.path)
    return m


def stored_checkpoint(warehouse: str, task: str, checkpoint_id: str | None = None) -> tuple[Manifest, dict]:
    """(the manifest, the `closed_loop_checkpoints` row) of a stored closed-loop policy: the given id, or the
    task's newest."""
    rows = read_table("closed_loop_checkpoints", warehouse, task=task).to_pylist()
    if checkpoint_id is not None:
        rows = [r for r in rows if r["checkpoint_id"] == checkpoint_id]
    if not rows:
        which = f" with id {checkpoint_id}" if checkpoint_id else ""
        raise ValueError(f"no closed-loop policy of task {task!r}{which}: train one with "
                         f"`demoforge train-policy --closed-loop --task {task}`")
    row = max(rows, key=lambda r: r["trained_at"])
    f = table_files("closed_loop_checkpoints", warehouse, task=task, take=row["take"], gripper=row["gripper"],
                    checkpoint_id=row["checkpoint_id"])[0]
    pt = Path(row["path"]) / "model.pt"
    files = [WrittenFile("closed_loop_checkpoints", str(f), 1, file_sha256(f))]
    if pt.is_file():
        files.append(WrittenFile("closed_loop_checkpoint_file", str(pt), 0, file_sha256(pt)))
    return Manifest.from_written("closed_loop_checkpoints", files, path=str(f)), row


@flow(name="eval-closed-loop-policy")
def eval_closed_loop(warehouse: str, checkpoint: Manifest, task: str, take: str, scenes: int = 50, seed: int = 0,
                     robot: RobotSpec | str = "aloha", gripper: str | None = "2f140", max_steps: int = 900) -> Manifest:
    """Roll a trained closed-loop policy out on `scenes` held-out scenes of its database's distribution."""
    arms = _arms(robot, gripper)
    return run_stage(closed_loop_trials, warehouse, task=task, take=take, warehouse=warehouse, robot=arms.name,
                     gripper=arms.gripper_name, method="closed_loop", database=database_inputs(warehouse, task, take),
                     screening=_screening(warehouse, task, take, arms), seed=seed, scenes=scenes,
                     checkpoint=checkpoint, max_steps=max_steps)


@flow(name="data-scaling")
def data_scaling(warehouse: str, tasks: Sequence[str] = ("pouring",), sizes: Sequence[int] = DEFAULT_SIZES,
                 scenes: int = 50, seed: int = 0, steps: int = 3000, robot: RobotSpec | str = "aloha",
                 gripper: str | None = "2f140", threads: int = 1, baselines: bool = True,
                 open_loop: bool = True) -> list[Manifest]:
    """The data-scaling table: per task, a closed-loop policy trained on each number of episodes in `sizes`
    (1 = the original demonstration alone), each rolled out on the same `scenes` held-out scenes, and the
    LLM-free baselines (`baselines`) and the open-loop keypoint policy (`open_loop`: trained on all screened-in
    episodes) on them (`closed_loop_trials`; the view `report_data_scaling`)."""
    if not sizes or min(sizes) < 1 or scenes < 1:
        raise ValueError("sizes must be numbers of episodes >= 1 and scenes at least 1")
    arms = _arms(robot, gripper)
    out = []
    for task in tasks:
        take = _resolve_take(warehouse, task, None)
        screening = _screening(warehouse, task, take, arms)
        database = database_inputs(warehouse, task, take)
        common = dict(task=task, take=take, warehouse=warehouse, robot=arms.name, gripper=arms.gripper_name,
                      database=database, screening=screening, seed=seed)
        for n in sorted(set(int(s) for s in sizes)):
            ck = run_stage(closed_loop_train, warehouse, n_episodes=n, steps=steps, threads=threads, **common)
            out.append(run_stage(closed_loop_trials, warehouse, method="closed_loop", scenes=scenes, checkpoint=ck,
                                 **common))
        for method in BASELINES if baselines else ():
            out.append(run_stage(closed_loop_trials, warehouse, method=method, scenes=scenes, **common))
        if not open_loop:
            continue
        policy = run_stage(policy_train, warehouse, task=task, take=take, warehouse=warehouse, database=database,
                           seed=seed, epochs=OPEN_LOOP_EPOCHS, max_seconds=None, threads=threads,
                           n_waypoints=OPEN_LOOP_WAYPOINTS, robot_label=arms.label, screening=screening)
        out.append(run_stage(closed_loop_trials, warehouse, method=OPEN_LOOP, scenes=scenes, checkpoint=policy,
                             **common))
    return out
