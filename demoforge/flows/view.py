"""The view flow (`demoforge view`): an offline Rerun recording (.rrd) of a take or an episode, with the
check the command makes before a run. The recording's format is lib/exports/rerun_view.py."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
from prefect import flow

from demoforge.lib.exports import ExportError
from demoforge.lib.exports.rerun_view import TakeFrame, write_episode_recording, write_take_recording
from demoforge.lib.takes import iter_frames, open_take
from demoforge.lib.task_library import TASK_NAMES, get_task
from demoforge.schemas.core import column_numpy, read_table, table_files
from demoforge.schemas.reads.episodes import check_name, read_steps


@flow(name="view")
def view_flow(warehouse: str, target: str, out: str, take: str | None = None, point_stride: int = 8,
              frame_step: int = 1, images: bool = True, depth_images: bool = False,
              overwrite: bool = False) -> dict:
    """A Rerun recording (.rrd) of a take or an episode, saved offline."""
    return write_view(warehouse, target, out, take, point_stride, frame_step, images, depth_images, overwrite)


def preflight_view(warehouse: str, target: str, take: str | None = None) -> dict:
    """Resolve TAKE_OR_EPISODE and check that it exists, before any Prefect run."""
    what = resolve_view_target(warehouse, target, take)
    if what["kind"] == "take" and not table_files("gripper_poses", warehouse, take=what["take_id"]):
        raise ExportError(f"take {what['take_id']} is not ingested in {warehouse}; run "
                          f"`demoforge ingest {what['path']}` first")
    if what["kind"] == "episode":
        eps = read_table("episodes", warehouse, columns=["episode_id"], task=what["task"], take=what["take"])
        if what["episode_id"] not in set(eps.column("episode_id").to_pylist()):
            raise ExportError(f"task {what['task']!r} (take {what['take']}) has no episode {what['episode_id']}")
    return what


def _episode_poses(warehouse: str, task: str, take: str, episode_id: int) -> np.ndarray:
    e, s, act = read_steps(warehouse, task, take)
    rows = np.flatnonzero(e == int(episode_id))
    if len(rows) == 0:
        raise ExportError(f"episode {episode_id} of task {task!r} (take {take}) has no steps; list the "
                          "episodes with `demoforge sql \"SELECT episode_id, kind, valid FROM episodes WHERE "
                          f"task = '{task}'\"`")
    return act[rows[np.argsort(s[rows], kind="stable")]].astype(np.float64)


def resolve_view_target(warehouse: str, target: str, take: str | None = None) -> dict:
    """What `demoforge view TARGET` means: a take folder, an ingested take's id, or TASK/EPISODE_ID."""
    p = Path(target)
    if p.is_dir():
        return {"kind": "take", "take_id": p.name, "path": p.resolve()}
    m = re.fullmatch(r"([A-Za-z0-9_]+)[/:](\d+)", target)
    if m:
        task, eid = m.group(1), int(m.group(2))
        check_name("task", task)
        if take is None:
            takes = sorted({f.parent.name.split("=", 1)[1] for f in table_files("episodes", warehouse, task=task)})
            if not takes:
                raise ExportError(f"no episodes of task {task!r} in {warehouse}; run `demoforge augment` first")
            take = takes[0]
        return {"kind": "episode", "task": task, "take": take, "episode_id": eid}
    check_name("take", target)
    rows = read_table("takes", warehouse).filter(pc.field("take") == target).to_pylist() \
        if table_files("takes", warehouse) else []
    if rows and Path(rows[0]["path"]).is_dir():
        return {"kind": "take", "take_id": target, "path": Path(rows[0]["path"])}
    raise ExportError(f"{target!r} is neither a take folder, a take registered in the warehouse, nor "
                      "TASK/EPISODE_ID (e.g. pouring/0)")


def write_view(warehouse: str, target: str, out: str, take: str | None = None, point_stride: int = 8,
               frame_step: int = 1, images: bool = True, depth_images: bool = False,
               overwrite: bool = False) -> dict:
    """Write the Rerun recording of a take or an episode to ``out``; returns what was logged."""
    if frame_step < 1:
        raise ExportError(f"--frame-step must be at least 1, got {frame_step}")
    what = resolve_view_target(warehouse, target, take)
    if what["kind"] == "episode":
        task, tk, eid = what["task"], what["take"], what["episode_id"]
        eps = read_table("episodes", warehouse, task=task, take=tk)
        row = np.flatnonzero(eps.column("episode_id").to_numpy() == eid)
        if len(row) == 0:
            raise ExportError(f"task {task!r} (take {tk}) has no episode {eid}")
        poses = _episode_poses(warehouse, task, tk, eid)
        ref = _episode_poses(warehouse, task, tk, 0) if eid != 0 else None
        names = get_task(task).keypoint_names if task in TASK_NAMES else None
        counts = write_episode_recording(out, name=f"{task}/{tk}/{eid}", poses=poses,
                                         object_keypoints=column_numpy(eps, "object_keypoints")[row[0]],
                                         keypoint_names=names, reference=ref, overwrite=overwrite)
        return {**what, **counts, "path": str(out)}

    take_obj = open_take(what["path"])
    tid = take_obj.take_id
    gp = read_table("gripper_poses", warehouse, take=tid)
    if gp.num_rows == 0:
        raise ExportError(f"take {tid} is not ingested in {warehouse}; run `demoforge ingest {what['path']}` first")
    T = take_obj.n_frames
    hands = np.full((T, 2, 21, 3), np.nan)
    present = np.zeros((T, 2), bool)
    grippers = np.full((T, 2, 8), np.nan)
    al = read_table("aligned_keypoints", warehouse, take=tid)
    g_hand, g_frame = np.asarray(gp.column("hand").to_pylist()), gp.column("frame").to_numpy()
    g_valid, g_pose = gp.column("valid").to_numpy(zero_copy_only=False), column_numpy(gp, "pose")
    a_hand, a_frame = np.asarray(al.column("hand").to_pylist()), al.column("frame").to_numpy()
    a_present, a_joints = al.column("present").to_numpy(zero_copy_only=False), column_numpy(al, "joints_world")
    for arm, hand in enumerate(("left", "right")):
        m = (g_hand == hand) & g_valid
        grippers[g_frame[m], arm] = g_pose[m]
        m = a_hand == hand
        hands[a_frame[m], arm] = a_joints[m]
        present[a_frame[m], arm] = a_present[m]
    ok_t = read_table("object_keypoints", warehouse, take=tid).sort_by("keypoint")
    kp = column_numpy(ok_t, "point_world") if ok_t.num_rows else None
    wanted = list(range(0, T, frame_step))

    def frames():
        for batch in iter_frames(take_obj, frames=wanted):
            for i, idx in enumerate(batch.indices.tolist()):
                yield TakeFrame(idx, idx / take_obj.fps, batch.rgb[i], batch.depth[i])

    cam = take_obj.camera
    counts = write_take_recording(out, take_id=tid, K=cam.K, T_world_camera=cam.T_world_camera, width=cam.width,
                                  height=cam.height, frames=frames(), hands_world=hands, hands_present=present,
                                  gripper_poses=grippers, object_keypoints=kp,
                                  keypoint_names=ok_t.column("name").to_pylist() if kp is not None else None,
                                  point_stride=point_stride, log_images=images,
                                  log_depth_images=depth_images, overwrite=overwrite)
    return {"kind": "take", "take_id": tid, **counts, "path": str(out)}
