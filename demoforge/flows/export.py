"""The export and view flows (`demoforge export`, `demoforge view`); the reading and writing they
compose is in demoforge.tasks.export."""

from __future__ import annotations

from pathlib import Path
from prefect import flow

import demoforge.lib  # noqa: F401
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.export import (
    refuse_to_replace_foreign_output, check_files, episode_files, export_lerobot_stage, export_robomimic_stage, write_view,
)


@flow(name="export-lerobot")
def export_lerobot_flow(warehouse: str, task: str, out: str, take: str | None = None,
                        include_invalid: bool = False, limit: int | None = None, with_images: bool = False,
                        image_size: tuple[int, int] | None = None, robot: str = "grippers",
                        gripper: str | None = None, unchecked: bool = False) -> Manifest:
    """A task's episodes as a LeRobotDataset v3.0 folder at ``out`` (replaces an earlier export there):
    the grippers' poses, or an arm robot's joint values (`robot`, `gripper`) of the episodes its check
    passed (all it reaches with `unchecked`)."""
    from demoforge.lib.sim.robots import get_robot

    arm = get_robot(robot, gripper)
    out_p = Path(out).resolve()
    refuse_to_replace_foreign_output(out_p, "meta/info.json")
    sources = episode_files(warehouse, task, take)
    if arm.joint_names and not unchecked:
        sources += check_files(warehouse, task, arm.name, arm.gripper_name)
    return run_stage(export_lerobot_stage, warehouse, sources=sources,
                     warehouse=warehouse, task=task, out=str(out_p), take=take, include_invalid=include_invalid,
                     limit=limit, with_images=with_images, image_size=image_size, robot=arm.name,
                     gripper=arm.gripper_name, unchecked=unchecked)


@flow(name="export-robomimic")
def export_robomimic_flow(warehouse: str, task: str, out: str, take: str | None = None,
                          include_invalid: bool = False, limit: int | None = None, valid_fraction: float = 0.1,
                          seed: int = 0) -> Manifest:
    """A task's episodes as one robomimic hdf5 file at ``out``."""
    out_p = Path(out).resolve()
    refuse_to_replace_foreign_output(out_p, None)
    return run_stage(export_robomimic_stage, warehouse, sources=episode_files(warehouse, task, take),
                     warehouse=warehouse, task=task, out=str(out_p), take=take, include_invalid=include_invalid,
                     limit=limit, valid_fraction=valid_fraction, seed=seed)


@flow(name="view")
def view_flow(warehouse: str, target: str, out: str, take: str | None = None, point_stride: int = 8,
              frame_step: int = 1, images: bool = True, depth_images: bool = False,
              overwrite: bool = False) -> dict:
    """A Rerun recording (.rrd) of a take or an episode, saved offline."""
    return write_view(warehouse, target, out, take, point_stride, frame_step, images, depth_images, overwrite)
