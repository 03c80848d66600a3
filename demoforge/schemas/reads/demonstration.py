"""An ingested take as the augmentation reads it: its gripper trajectory with the undetected frames
filled, its object keypoints and segments, and the task (the task library's, or the take's own
annotated one) as the augmentation's DemoSource."""

from __future__ import annotations

import numpy as np

from demoforge.lib.task_library import TASK_NAMES, get_task
from demoforge.lib.trajectories.augmentation import DemoSource
from demoforge.lib.trajectories.segmentation import Segment, fill_invalid_poses, infer_object_arm
from demoforge.schemas.core import read_table
from demoforge.schemas.reads.per_hand import arrays


def demo_arrays(take_id: str, task: str, warehouse: str) -> tuple[np.ndarray, np.ndarray]:
    """The take's gripper trajectory (T, 2, 8) with undetected frames filled, and its object keypoints."""
    part = dict(task=task, take=take_id)
    _, gp = arrays(read_table("gripper_poses", warehouse, **part), "pose", "valid")
    traj = fill_invalid_poses(gp["pose"], gp["valid"])
    ok = read_table("object_keypoints", warehouse, **part).sort_by("keypoint")
    kp = np.array(ok.column("point_world").to_pylist(), float)
    if not np.isfinite(kp).all():
        bad = [n for n, v in zip(ok.column("name").to_pylist(), ok.column("valid").to_pylist()) if not v]
        raise ValueError(f"take {take_id}: object keypoints without depth: {bad}; fix the annotation "
                         "(click points on valid depth) before augmenting")
    return traj, kp


def require_task(task: str, take=None):
    """The task library's Task, or for a custom task the TaskDefinition of the take's annotations.json."""
    if task in TASK_NAMES:
        return get_task(task)
    defined = getattr(getattr(take, "annotations", None), "task", None)
    if defined is not None and not defined.library and defined.name == task:
        return defined
    raise ValueError(f"task {task!r} is not in the task library ({', '.join(TASK_NAMES)}); ingest the "
                     "take with --task NAME so its objects and keypoints are known, or annotate it as a task "
                     "of your own (demoforge annotate TAKE --task custom --keypoints ...)")


def load_demo_source(take_id: str, task: str, warehouse: str, take=None):
    """The ingested demonstration as the augmentation's DemoSource: gripper trajectory, object
    keypoints and segments from the warehouse, object models from the task library (a custom task:
    its annotated first frame). The arm of each object is the one annotations.json states, else
    inferred from which hand holds it."""
    spec = require_task(task, take)
    traj, kp = demo_arrays(take_id, task, warehouse)
    rows = read_table("segments", warehouse, task=task, take=take_id).to_pylist()
    segs = [Segment(r["arm"], r["kind"], r["start"], r["end"], r["object"]) for r in rows]
    ko = np.asarray(spec.keypoint_object, int)
    local = spec.keypoints_local(kp) if callable(spec.keypoints_local) else spec.keypoints_local
    defined = getattr(getattr(take, "annotations", None), "task", None)
    stated = defined.object_arm_index() if defined is not None and defined.name == task else None
    return DemoSource(task=task, trajectory=traj, keypoints=kp, keypoint_object=ko, keypoints_local=local,
                      segments=segs, object_arm=stated if stated is not None else infer_object_arm(traj, kp, ko),
                      workspace=None if callable(spec.workspace) else spec.workspace)
