"""The export flows (`demoforge export`) and the checks the command makes before a run; the stages they
compose are in demoforge.tasks.export, the episodes they read in demoforge.schemas.reads.episodes."""

from __future__ import annotations

from pathlib import Path
from prefect import flow

from demoforge.lib.exports import ExportError
from demoforge.lib.exports.robomimic import is_demoforge_robomimic
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.task_library import TASK_NAMES
from demoforge.schemas.reads.episodes import check_files, checked_episodes, episode_files, take_cameras
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.export import export_lerobot_stage, export_robomimic_stage


@flow(name="export-lerobot")
def export_lerobot_flow(warehouse: str, task: str, out: str, take: str | None = None,
                        include_invalid: bool = False, limit: int | None = None, with_images: bool = False,
                        image_size: tuple[int, int] | None = None, robot: str = "grippers",
                        gripper: str | None = None, unchecked: bool = False) -> Manifest:
    """A task's episodes as a LeRobotDataset v3.0 folder at ``out`` (replaces an earlier export there):
    the grippers' poses, or an arm robot's joint values (`robot`, `gripper`) of the episodes its check
    passed (all it reaches with `unchecked`)."""
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


def refuse_to_replace_foreign_output(out: Path, marker: str | None) -> None:
    """An existing --out is only replaced when it is an export of the same kind (never a random folder)."""
    if not out.exists():
        return
    if marker is None and out.is_file():
        if is_demoforge_robomimic(out):
            return
    if marker is not None and (out / marker).is_file():
        return
    raise ExportError(f"{out} exists and is not a demoforge export of this kind; choose another --out")


def preflight_export(warehouse: str, task: str, out: str, fmt: str, take: str | None = None,
                     with_images: bool = False, robot: str = "grippers", gripper: str | None = None,
                     unchecked: bool = False) -> None:
    """The checks that need no Prefect run: known task, episodes present, --out not someone else's,
    with images every source take's camera, and for an arm robot's export (unless unchecked) episodes
    whose check with it passed."""
    if task not in TASK_NAMES:
        raise ExportError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    if fmt == "robomimic" and Path(out).suffix not in (".hdf5", ".h5"):
        raise ExportError(f"--out {out} must end in .hdf5 (or .h5) for robomimic")
    refuse_to_replace_foreign_output(Path(out).resolve(), "meta/info.json" if fmt == "lerobot" else None)
    files = episode_files(warehouse, task, take)
    if robot != "grippers" and not unchecked:
        arm = get_robot(robot, gripper)
        checked_episodes(warehouse, task, arm.name, arm.gripper_name, take)
    if with_images:
        take_cameras(warehouse, [take] if take else sorted({f.parent.name.split("=", 1)[1] for f in files
                                                            if f.parent.name.startswith("take=")}))
