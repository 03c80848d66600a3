"""Prefect tasks of the robot success check: one chunk of a task's episodes executed in MuJoCo, once
(simulate_chunk) or repeated on rigidly shifted copies of the scene (stability_chunk)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.errors import UserError, one_line
from demoforge.lib.sim import execute, sim_options
from demoforge.lib.sim.stability import scene_offsets, shift_scene
from demoforge.lib.takes import take_task_name
from demoforge.lib.task_library import TASK_LIBRARY_VERSION  # noqa: F401  (scenes: part of the code version)
from demoforge.lib.trajectories.segmentation import fill_invalid_poses
from demoforge.schemas.catalog import placeholders, query
from demoforge.schemas.core import read_table, read_table_file, write_table
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.schemas.reads.per_hand import arrays
from demoforge.tasks.common import Manifest, opened_take, stage_task

# 2: settle phase stopped at rest, constraint islands off (lib/sim)
# 3: results per selection; the key holds the episode database's content and the scene fingerprint
# 4: results per robot (lib/sim/robots), with the arms' IK residual
SIM_VERSION = "4"


def _load_episodes(task: str, take: str, episode_ids, warehouse: str):
    """(ids, kinds, object keypoints (n, K, 3), {id: actions (L, 2, 8)}) of episodes of a take's database."""
    ids = [int(i) for i in episode_ids]
    ep = query("SELECT episode_id, kind, object_keypoints FROM episodes WHERE task = ? AND take = ? "
               f"AND episode_id IN ({placeholders(len(ids))}) ORDER BY episode_id", warehouse, [task, take, *ids])
    eids = [int(i) for i in ep.column("episode_id").to_pylist()]
    missing = sorted(set(int(i) for i in episode_ids) - set(eids))
    if missing:
        raise ValueError(f"{task}/{take}: no such episodes {missing[:10]}")
    kinds = ep.column("kind").to_pylist()
    kps = np.asarray(ep.column("object_keypoints").to_pylist(), float)
    return eids, kinds, kps, episode_actions(warehouse, task, take, eids)


def _execute_with_bar(task: str, jobs: list, workers: int, desc: str, show_progress: bool, options=None) -> list:
    """demoforge.lib.sim.execute_many with a progress bar (closed even when a worker fails)."""
    from demoforge.lib.sim import execute_many  # imported when called: tests replace what it names

    bar = None
    if show_progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc=desc, unit="episode", leave=False, position=1)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    try:
        return execute_many(task, jobs, workers=workers, progress=progress, options=options)
    finally:
        if bar is not None:
            bar.close()


def _outcome_columns(r) -> dict:
    """The outcome columns `sim_results` and `sim_stability` share, from a demoforge.lib.sim.SimResult."""
    return {"success": bool(r.success), "failure": "" if r.success else str(r.failure or ""),
            "detail": str(r.detail or ""), "wall_s": float(r.wall_s or 0.0)}


def _ik_columns(r) -> dict:
    """The arms' IK residual and time-scale of a SimResult (null for a robot without arms, or an episode refused
    before IK)."""
    ik = r.robot or {}
    return {"reachable": ik.get("reachable"), "ik_position_error_m": ik.get("ik_position_error_m"),
            "ik_rotation_error_deg": ik.get("ik_rotation_error_deg"), "time_scale": ik.get("time_scale")}


@stage_task(name="simulate_chunk", version=SIM_VERSION, key_ignore=("workers",))
def simulate_chunk(task: str, take: str, selection: str, chunk: int, episode_ids: list[int], warehouse: str,
                   source: list[Path], scene: str, workers: int = 2, show_progress: bool = True,
                   robot: str = "grippers", gripper: str | None = None) -> Manifest:
    """Execute the given episodes with the robot (lib/sim/robots: `robot` with hand `gripper`) and write
    their `sim_results` rows.

    `source`: the take's `episodes` and `episode_steps` files and `scene`: demoforge.lib.sim.scene_fingerprint,
    both only in the cache key, so re-augmenting a take or changing a task's objects or the robot makes
    the chunk run again instead of returning results of other episodes."""
    opt = sim_options(robot, gripper)
    eids, kinds, kps, acts = _load_episodes(task, take, episode_ids, warehouse)
    results = _execute_with_bar(task, [{"keypoints": kps[k], "actions": acts[e]} for k, e in enumerate(eids)],
                                workers, f"{task} chunk {chunk} ({opt.robot.label})", show_progress, opt)
    rows = []
    for e, kind, r in zip(eids, kinds, results):
        rows.append({"task": task, "take": take, "robot": opt.robot.name, "gripper": opt.robot.gripper_name,
                     "selection": selection, "chunk": int(chunk), "episode_id": e,
                     "kind": kind, **_outcome_columns(r), "predicate_ok": r.predicate_ok,
                     "predicate_detail": str(r.predicate_detail or ""), **_ik_columns(r),
                     "duration_s": float(r.duration_s or 0.0), "physics_steps": int(r.physics_steps or 0)})
    written = write_table("sim_results", pa.Table.from_pylist(rows), warehouse)
    return Manifest.from_written("sim_results", written)


@stage_task(name="stability_chunk", version=SIM_VERSION, key_ignore=("workers",))
def stability_chunk(task: str, take: str, run: str, chunk: int, episode_ids: list[int], repeats: int,
                    jitter_m: float, seed: int, warehouse: str, source: list[Path], scene: str, workers: int = 2,
                    show_progress: bool = True, robot: str = "grippers", gripper: str | None = None) -> Manifest:
    """Execute each of the given episodes `repeats` times, repeat 0 as is and the others with the scene
    shifted rigidly by demoforge.lib.sim.stability.scene_offsets, and write their `sim_stability` rows.
    `source` and `scene` are in the cache key only, as for simulate_chunk."""
    opt = sim_options(robot, gripper)
    eids, kinds, kps, acts = _load_episodes(task, take, episode_ids, warehouse)
    offsets = scene_offsets(eids, repeats, jitter_m, seed)
    jobs, keys = [], []
    for k, e in enumerate(eids):
        for r in range(repeats):
            kp, a = shift_scene(kps[k], acts[e], offsets[k, r])
            jobs.append({"keypoints": kp, "actions": a})
            keys.append((k, r))
    results = _execute_with_bar(task, jobs, workers, f"{task} stability chunk {chunk} ({opt.robot.label})",
                                show_progress, opt)
    rows = []
    for (k, r), res in zip(keys, results):
        rows.append({"task": task, "take": take, "robot": opt.robot.name, "gripper": opt.robot.gripper_name,
                     "run": run, "chunk": int(chunk), "episode_id": eids[k],
                     "kind": kinds[k], "repeat": r, "jitter_m": float(jitter_m),
                     "offset_x": float(offsets[k, r, 0]), "offset_y": float(offsets[k, r, 1]),
                     **_outcome_columns(res)})
    written = write_table("sim_stability", pa.Table.from_pylist(rows), warehouse)
    return Manifest.from_written("sim_stability", written)


def demo_failure_row(task: str, take: str, detector: str, status: str, detail: str) -> pa.Table:
    """An `ingested_demo_checks` row for a demonstration that could not be executed."""
    return pa.Table.from_pylist([{
        "task": task, "take": take, "detector": detector, "status": status, "success": False, "failure": status,
        "detail": detail[:2000], "frames": 0, "valid_left": None, "valid_right": None, "trusted_hands": None,
        "wall_s": 0.0}])


@stage_task(name="check_ingested_demo", version=f"{SIM_VERSION}/demo-1")
def check_ingested_demo(take_dir: Path, task: str | None, warehouse: str, grippers: Manifest, objects: Manifest,
                        presence: Manifest, scene: str, variant: dict | None = None) -> Manifest:
    """Execute the take's ingested demonstration (its `gripper_poses` of the given variant, undetected
    frames held at the nearest valid pose like the episode database's episode 0; its object keypoints) in
    MuJoCo and write its `ingested_demo_checks` row. `scene` (demoforge.lib.sim.scene_fingerprint) is in the
    cache key only, as for simulate_chunk."""
    take = opened_take(take_dir)  # the take the ingest that ran before opened
    name = take_task_name(take, task)
    part = dict(task=name, take=take.take_id)
    gp_t = read_table("gripper_poses", warehouse, variant=variant, **part)
    T, gp = arrays(gp_t, "pose", "valid")
    detector = gp_t.column("detector")[0].as_py()
    trusted = sum(bool(r["trusted"]) for f in presence.files for r in read_table_file("hand_presence", f).to_pylist())
    ok = read_table("object_keypoints", warehouse, **part).sort_by("keypoint")
    kp = np.array(ok.column("point_world").to_pylist(), float)
    valid = gp["valid"].astype(bool)
    row = {"task": name, "take": take.take_id, "detector": detector, "frames": int(T),
           "valid_left": float(valid[:, 0].mean()) if T else None,
           "valid_right": float(valid[:, 1].mean()) if T else None, "trusted_hands": int(trusted)}
    try:
        traj = fill_invalid_poses(gp["pose"], valid)
    except UserError as e:
        row.update(status="no_trajectory", success=False, failure="no_trajectory", detail=one_line(e)[:2000],
                   frames=0, wall_s=0.0)
    else:
        r = execute(name, kp, traj)
        row.update(status="executed", **_outcome_columns(r))
    written = write_table("ingested_demo_checks", pa.Table.from_pylist([row]), warehouse)
    return Manifest.from_written("ingested_demo_checks", written)
