"""Prefect tasks of the closed-loop policy: train it on n screened-in episodes of a database in an arm
robot's joint space (-> `closed_loop_checkpoints`), and roll it out on held-out scenes in the task's
Gymnasium environment beside the LLM-free baselines on the same scenes (-> `closed_loop_trials`)."""

from __future__ import annotations

import json
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.envs.rollout import rollout
from demoforge.envs.scenes import draw_scene
from demoforge.lib.policy.joint_demos import joint_demos
from demoforge.lib.sim import SimOptions, execute
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import transform_demo
from demoforge.lib.trajectories.retrieval import KeypointIndex
from demoforge.schemas.core import WrittenFile, file_sha256, get_schema, read_table_file, write_table
from demoforge.schemas.reads.demonstration import load_demo_source
from demoforge.schemas.reads.episodes import episode_actions, load_episodes
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.llm_eval import upsample
from demoforge.tasks.policy import checkpoint_row as policy_row
from demoforge.tasks.table3 import _database, nearest_source

CLOSED_LOOP_VERSION = "3"  # 3: episodes drawn from the valid screened-in ones only
CLOSED_LOOP_DIR = "_closed_loop"  # checkpoints beside the warehouse tables, like _policy
SCENE_SEED_BASE = 1_000_000       # held-out scene seeds: seed * 10,000 + i above it; no database uses them
BASELINES = ("replay_top1", "transform_demo")
OPEN_LOOP = "open_loop"           # the keypoint-to-trajectory policy (lib/policy/model.py), executed by the robot check
SUCCESS_CHECK_EVERY = 15          # frames: a rollout ends once the task's success predicate holds (checked every 0.5 s)


def training_episode_ids(warehouse: str, task: str, take: str, robot_label: str, n: int, seed: int) -> np.ndarray:
    """The episodes a policy of n episodes trains on: the original demonstration, then n - 1 valid screened-in
    episodes drawn with the seed (the draws of a larger n start with those of a smaller one)."""
    db = _database(warehouse, task, take, robot_label)  # valid, screened in, and the original
    original = int(db["ids"][db["kinds"] == "original"][0])
    pool = np.setdiff1d(db["ids"], [original])
    if n - 1 > len(pool):
        raise ValueError(f"{task}/{take} has {len(pool)} valid screened-in episodes for {robot_label}, fewer than the "
                         f"{n - 1} asked for: ask for fewer episodes or augment a larger database")
    drawn = np.random.default_rng([int(seed), 47]).permutation(pool)[:n - 1]
    return np.concatenate([[original], np.sort(drawn)]).astype(np.int64)


def held_out_scenes(task: str, source, seed: int, n: int) -> list[dict]:
    """n thesis-protocol scenes of the database's distribution (envs/scenes.py draw_scene) from the held-out
    seeds SCENE_SEED_BASE + seed * 10,000 + i, each with its seed."""
    spec = get_task(task)
    out = []
    for i in range(n):
        s = SCENE_SEED_BASE + int(seed) * 10_000 + i
        out.append({**draw_scene(spec, "thesis", np.random.default_rng(s), source), "scene_seed": s})
    return out


@stage_task(name="closed_loop_train", version=CLOSED_LOOP_VERSION, key_ignore=("threads",))
def closed_loop_train(task: str, take: str, warehouse: str, robot: str, gripper: str, n_episodes: int,
                      screening: Manifest, database: dict, seed: int = 0, steps: int = 3000, threads: int = 1
                      ) -> Manifest:
    """Train one closed-loop policy on n_episodes of task/take (training_episode_ids) as the arms execute them;
    write its checkpoint and a `closed_loop_checkpoints` row."""
    from tqdm.auto import tqdm

    from demoforge.lib.policy.chunk_train import ChunkTrainConfig, chunk_checkpoint_id, save_chunk_checkpoint, \
        train_chunk_policy  # lazy: mujoco, torch

    arm = get_robot(robot, gripper)
    ids = training_episode_ids(warehouse, task, take, arm.label, n_episodes, seed)
    sel = load_episodes(warehouse, task, take, only={(take, int(i)) for i in ids})
    t0 = time.perf_counter()
    with tqdm(total=len(ids), desc=f"{task}: {len(ids)} episodes in joint space", unit="episode", disable=None) as bar:
        demos = joint_demos(arm, get_task(task), sel.poses, sel.lengths, sel.keypoints,
                            progress=lambda i: bar.update(i - bar.n))
    plan_s = time.perf_counter() - t0
    tc = ChunkTrainConfig(steps=steps, threads=threads)
    with tqdm(total=steps, desc=f"{task}: train on {len(demos)} episodes", unit="step", disable=None,
              mininterval=1.0) as bar:
        res = train_chunk_policy(demos, train=tc, seed=seed, on_step=lambda s, total: bar.update(1))
    cid = chunk_checkpoint_id(res.model)
    folder = Path(warehouse) / CLOSED_LOOP_DIR / task / take / arm.label / cid
    config = {"policy": res.model.config.to_dict(), "train": tc.to_dict()}
    pt = save_chunk_checkpoint(res.model, folder, {"task": task, "take": take, "robot": arm.label, "seed": seed,
                                                    "episode_ids": ids.tolist(), "losses": res.losses})
    row = {"task": task, "take": take, "robot": arm.label, "gripper": arm.gripper_name, "checkpoint_id": cid,
           "path": str(folder), "n_requested": int(n_episodes), "n_episodes": res.episodes, "frames": res.frames,
           "seed": int(seed), "steps": int(steps), "threads": int(threads), "plan_seconds": plan_s,
           "train_seconds": res.seconds, "final_loss": res.losses[-1], "config": json.dumps(config, sort_keys=True),
           "trained_at": datetime.now(timezone.utc)}
    schema = get_schema("closed_loop_checkpoints").arrow
    written = write_table("closed_loop_checkpoints", pa.Table.from_pylist([row], schema=schema), warehouse)
    files = list(written) + [WrittenFile("closed_loop_checkpoint_file", str(pt), 0, file_sha256(pt))]
    return Manifest.from_written("closed_loop_checkpoints", files, path=written[0].path)


def checkpoint_row(manifest: Manifest) -> dict:
    return read_table_file("closed_loop_checkpoints", manifest.path).to_pylist()[0]


def _row(task, take, arm, method, checkpoint_id, n_train, scene, out, inference_ms=0.0) -> dict:
    return {"task": task, "take": take, "robot": arm.label, "gripper": arm.gripper_name, "method": method,
            "checkpoint_id": checkpoint_id, "n_train_episodes": int(n_train), "scene_seed": int(scene["scene_seed"]),
            "scene_mirrored": bool(scene["mirrored"]), "success": bool(out["success"]),
            "failure": str(out["failure"] or ""), "detail": str(out["detail"])[:500], "frames": int(out["frames"]),
            "rollout_seconds": float(out["seconds"]), "inference_ms_per_step": float(inference_ms)}


@stage_task(name="closed_loop_trials", version=CLOSED_LOOP_VERSION, key_optional=("checkpoint",))
def closed_loop_trials(task: str, take: str, warehouse: str, robot: str, gripper: str, method: str,
                       database: dict, screening: Manifest, seed: int = 0, scenes: int = 50,
                       checkpoint: Manifest | None = None, max_steps: int = 900) -> Manifest:
    """See _trials; `checkpoint`: the closed-loop policy's (`closed_loop`) or the open-loop policy's
    (`open_loop`: a `policy_checkpoints` manifest)."""
    return _trials(task, take, warehouse, robot, gripper, method, seed, scenes, checkpoint, max_steps)


def _executed_rows(task, take, warehouse, arm, method, bar, source, checkpoint: Manifest | None) -> list[dict]:
    """A method whose trajectory the robot check executes, on each scene: `replay_top1` (the nearest valid
    screened-in episode), `transform_demo`, or `open_loop` (the keypoint policy's waypoints upsampled to the scene
    layout's episode length, as Table 3's `policy` column)."""
    db = _database(warehouse, task, take, arm.label)
    checkpoint_id, n_train, policy = "none", len(db["ids"]), None
    if method == OPEN_LOOP:
        from demoforge.lib.policy.train import load_checkpoint  # lazy: torch

        if checkpoint is None:
            raise ValueError("method open_loop needs a trained keypoint policy (policy_checkpoints)")
        ck = policy_row(checkpoint)
        checkpoint_id, n_train, policy = ck["checkpoint_id"], ck["n_train"], load_checkpoint(ck["path"])
    else:
        index = KeypointIndex(db["keypoints"], ids=db["ids"])
    original = np.flatnonzero(db["kinds"] == "original")[0]
    options, rows = SimOptions(robot=arm), []
    for sc in bar:
        t0 = time.perf_counter()
        kp = np.asarray(sc["keypoints"], float)
        inference = 0.0
        if method == OPEN_LOOP:
            layout = db["kinds"] == ("mirrored" if sc["mirrored"] else "original")
            n_steps = int(db["length"][layout][0] if layout.any() else db["length"][original])
            actions = upsample(policy.predict(kp, np.asarray(sc["initial"], float)), n_steps)
            inference = time.perf_counter() - t0
        elif method == "replay_top1":
            top = int(np.asarray(index.query(kp, k=1).ids).ravel()[0])
            actions = episode_actions(warehouse, task, take, [top])[top]
        else:
            actions = transform_demo(nearest_source(source, kp), np.asarray(sc["object_poses"], float))
        res = execute(task, kp, actions, options=options)
        out = {"success": res.success, "failure": res.failure, "detail": res.detail, "frames": res.n_frames,
               "seconds": time.perf_counter() - t0}
        rows.append(_row(task, take, arm, method, checkpoint_id, n_train, sc, out,
                         1000 * inference / max(res.n_frames, 1)))
    return rows


def _trials(task, take, warehouse, robot, gripper, method, seed, scenes, checkpoint, max_steps) -> Manifest:
    """Roll one method out on the held-out scenes of task/take: `closed_loop` (the checkpoint's policy stepping
    DemoforgeEnv with temporal ensembling, ended at the task's success or after max_steps frames, as a policy
    evaluation ends), or what the robot check executes of the open-loop policy or a baseline (_executed_rows);
    `closed_loop_trials` rows."""
    from tqdm.auto import tqdm

    from demoforge.envs.robot_env import DemoforgeEnv  # lazy: mujoco

    arm = get_robot(robot, gripper)
    source = load_demo_source(take, task, warehouse)
    rows = []
    todo = held_out_scenes(task, source, seed, scenes)
    bar = tqdm(todo, desc=f"{task}: {method} on {scenes} held-out scenes", unit="scene", disable=None)
    if method == "closed_loop":
        # lazy: mujoco, torch
        from demoforge.lib.policy.chunk_train import load_chunk_checkpoint
        from demoforge.lib.policy.chunking import TemporalEnsemble

        if checkpoint is None:
            raise ValueError("method closed_loop needs a trained checkpoint")
        ck = checkpoint_row(checkpoint)
        policy = TemporalEnsemble(load_chunk_checkpoint(ck["path"]))
        env = DemoforgeEnv(task, robot=arm.name, gripper=arm.gripper_name, max_steps=max_steps,
                           check_success_every=SUCCESS_CHECK_EVERY)
        for sc in bar:
            out = rollout(env, policy, options={"scene": sc})
            ms = 1000 * policy.inference_s / max(out["frames"], 1)
            rows.append(_row(task, take, arm, method, ck["checkpoint_id"], ck["n_episodes"], sc, out, ms))
        env.close()
    elif method == OPEN_LOOP or method in BASELINES:
        rows = _executed_rows(task, take, warehouse, arm, method, bar, source, checkpoint)
    else:
        raise ValueError(f"unknown method {method!r}; choose from closed_loop, {OPEN_LOOP}, {', '.join(BASELINES)}")
    schema = get_schema("closed_loop_trials").arrow
    written = write_table("closed_loop_trials", pa.Table.from_pylist(rows, schema=schema), warehouse)
    return Manifest.from_written("closed_loop_trials", written)
