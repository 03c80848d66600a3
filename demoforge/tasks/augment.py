"""Prefect tasks of segmentation and augmentation (thesis 3.2-3.3) over an ingested take."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.screening import screen_episodes
from demoforge.lib.takes import take_task_name
from demoforge.lib.trajectories.augmentation import generate_episodes
from demoforge.lib.trajectories.augmentation.servable import generate_servable
from demoforge.lib.trajectories.segmentation import Segment, boundaries, boundary_error, segment_trajectory
from demoforge.schemas.core import file_sha256, read_table_file, table_files, write_table
from demoforge.schemas.reads.demonstration import demo_arrays, load_demo_source, require_task
from demoforge.schemas.sim import drop_results
from demoforge.tasks.common import Manifest, opened_take, stage_task

# 2: the held object named by hull distance (trajectories/segmentation.py held_objects)
AUGMENT_VERSION = "2"


@stage_task(name="segment_take", version=AUGMENT_VERSION)
def segment_take(take_dir: Path, task: str | None, warehouse: str, grippers: Manifest, objects: Manifest,
                 manual: dict | None = None) -> Manifest:
    """Motion/skill segments per arm; on synthetic takes also the boundary error against the script."""
    take = opened_take(take_dir)
    name = take_task_name(take, task)
    spec = require_task(name, take)
    traj, kp = demo_arrays(take.take_id, name, warehouse)
    manual_arms = {int(k): list(v) for k, v in (manual or {}).items()}
    segs = segment_trajectory(traj, kp, spec.keypoint_object, manual=manual_arms or None)
    written = write_table("segments", {
        "take": [take.take_id] * len(segs), "task": [name] * len(segs),
        "arm": [s.arm for s in segs], "kind": [s.kind for s in segs], "start": [s.start for s in segs],
        "end": [s.end for s in segs], "object": [s.object for s in segs],
        "method": ["manual" if s.arm in manual_arms else "auto" for s in segs],
    }, warehouse)
    if take.has_ground_truth:
        gt = read_table_file("gt_segments", take.ground_truth_dir / "gt_segments.parquet").to_pylist()
        ref = [Segment(0 if r["hand"] == "left" else 1, r["kind"], r["start"], r["end"], -1) for r in gt]
        rows = []
        for arm in (0, 1):
            mine = [s for s in segs if s.arm == arm]
            theirs = [s for s in ref if s.arm == arm]
            e = boundary_error(mine, theirs)
            n_true = len(boundaries(theirs, arm))
            rows.append({"take": take.take_id, "task": name, "arm": arm, "boundaries_true": n_true,
                         "boundaries_found": len(boundaries(mine, arm)), "matched": n_true - e["missed"],
                         "mean_error_frames": None if np.isnan(e["mean"]) else e["mean"],
                         "max_error_frames": None if np.isnan(e["max"]) else e["max"]})
        written += write_table("segmentation_metrics", pa.Table.from_pylist(rows), warehouse)
    return Manifest.from_written("segments", written)


@stage_task(name="augment_take", version=AUGMENT_VERSION, key_optional=("screening_code",))
def augment_take(take_dir: Path, task: str | None, warehouse: str, grippers: Manifest, objects: Manifest,
                 segments: Manifest, n: int = 10_000, n_mirrored: int = 5_000, seed: int = 0,
                 options: dict | None = None, database: str | None = None, robot: str | None = None,
                 gripper: str | None = None, redraw_rounds: int = 8, screening_code: list[Path] | None = None) -> Manifest:
    """The task database: the demonstration, n - n_mirrored translated and n_mirrored mirrored episodes.
    database: the key written to `episodes.take` (default: the take's id); another key keeps a second
    database of the same take (other augmentation options) beside the first. robot (an arm robot, e.g.
    "aloha" with its gripper): the placements the arms' screening rejects are drawn again, up to
    redraw_rounds rounds (lib/trajectories/augmentation/servable.py). screening_code: the screening's
    sources (tasks/screening.py code_files), only in the cache key: a database drawn for the arms is drawn
    again when their planner or the task library changes."""
    take = opened_take(take_dir)
    name = take_task_name(take, task)
    spec = require_task(name, take)
    source = load_demo_source(take.take_id, name, warehouse, take)
    opts = dict(options or {})
    ws = spec.workspace(source.keypoints, source.trajectory[..., :3]) if callable(spec.workspace) else spec.workspace
    opts.setdefault("workspace", np.asarray(ws))
    if robot is None:
        batch = generate_episodes(source, n=n, n_mirrored=n_mirrored, seed=seed, **opts)
    else:
        batch = _servable_batch(source, name, robot, gripper, n, n_mirrored, seed, redraw_rounds, opts)
    key = database or take.take_id
    before = _episode_file_digests(warehouse, name, key)
    written = write_table("episodes", episodes_columns(name, key, seed, batch), warehouse)
    written += write_table("episode_steps", episode_steps_columns(name, key, batch), warehouse)
    if before and before != {w.path: w.content_hash for w in written}:  # the writer's sha256 of each file
        # the take's robot checks describe episodes that no longer exist: drop them, so that no
        # report or query mixes them with the new database (simulate again to refill)
        from prefect import get_run_logger

        gone = drop_results(warehouse, name, key)
        if gone:
            get_run_logger().warning("%s/%s: the episodes changed; removed %d robot-check file(s) (sim_results, "
                                     "sim_stability) of the previous episodes", name, take.take_id, gone)
    return Manifest.from_written("episodes", written)


def _servable_batch(source, task: str, robot: str, gripper: str | None, n: int, n_mirrored: int, seed: int,
                    rounds: int, opts: dict):
    """The database drawn where the robot's arms can serve it (every redraw screened as `screen` does)."""
    from prefect import get_run_logger
    from tqdm.auto import tqdm

    arms = get_robot(robot, gripper)

    def serves(batch, rows):
        return screen_episodes(arms, task, batch.episode_actions(rows), batch.lengths[rows],
                               batch.keypoints[rows]).executable

    log = get_run_logger()
    with tqdm(total=n + 1, desc=f"{task}: placements {arms.label} serves", unit="episode", disable=None) as bar:
        def progress(r: int, missing: int, ok: int) -> None:
            bar.set_postfix_str(f"redraw round {r}, {missing} drawn again")
            bar.update(ok - bar.n)

        draw = generate_servable(source, serves, n=n, n_mirrored=n_mirrored, seed=seed, rounds=rounds,
                                 progress=progress, **opts)
    log.info("%s: %d of %d episodes' placements served by %s (%.1f %%) after %d redraw round(s), %d judged",
             task, int(draw.served.sum()), len(draw.served), arms.label, 100 * draw.share, draw.rounds, draw.judged)
    return draw.batch


def _episode_file_digests(warehouse: str, task: str, take: str) -> dict[str, str]:
    """{path: sha256} of the take's `episodes` and `episode_steps` files (empty before the first write)."""
    files = [*table_files("episodes", warehouse, task=task, take=take),
             *table_files("episode_steps", warehouse, task=task, take=take)]
    return {str(f): file_sha256(f) for f in files}


def episodes_columns(task: str, take: str, seed: int, batch) -> dict:
    """One `episodes` row per generated episode of ``batch`` (demoforge.lib.trajectories.augmentation.EpisodeBatch)."""
    N = len(batch)
    return {
        "task": [task] * N, "take": [take] * N, "episode_id": batch.episode_id.astype(np.int64),
        "kind": batch.kind.astype(str).tolist(), "seed": np.full(N, seed, np.int64),
        "transform": batch.params.astype(np.float64), "object_keypoints": batch.keypoints,
        "initial_poses": batch.initial, "length": batch.lengths.astype(np.int32), "valid": batch.valid,
        "reject_reason": batch.reject_reason.astype(str).tolist(),
        "min_gripper_distance": batch.min_gripper_distance,
    }


def episode_steps_columns(task: str, take: str, batch) -> dict:
    """One row per (episode, step) from the padded (N, L, 2, 8) actions, without Python loops."""
    actions = batch.actions
    N, L = actions.shape[:2]
    if (batch.lengths == L).all():  # the usual case (timing kept): no padding, a free reshape
        ep = np.repeat(batch.episode_id.astype(np.int64), L)
        step = np.tile(np.arange(L, dtype=np.int32), N)
        action = actions.reshape(N * L, 2, 8)
    else:
        keep = np.arange(L)[None, :] < batch.lengths[:, None]                  # (N, L)
        ep = np.broadcast_to(batch.episode_id.astype(np.int64)[:, None], keep.shape)[keep]
        step = np.broadcast_to(np.arange(L, dtype=np.int32)[None, :], keep.shape)[keep]
        action = actions[keep]
    rows = len(ep)
    return {"task": pa.array([task]).take(np.zeros(rows, np.int64)),
            "take": pa.array([take]).take(np.zeros(rows, np.int64)),
            "episode_id": ep, "step": step, "action": action.astype(np.float32, copy=False)}
