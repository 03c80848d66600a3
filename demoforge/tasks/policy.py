"""Prefect tasks of the learned policy: train on a task's episode database; evaluate on the prompting
evaluation's query scenes, out-of-distribution placements and mirrored scenes with the MuJoCo check."""

from __future__ import annotations

import json
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.policy.data import PolicyData, resample_batch, split_by_placement
from demoforge.lib.policy.scenes import MIRROR, in_box, ood_placement, placement_offsets, translation_box
from demoforge.lib.sim import execute
from demoforge.lib.sim.executor import object_poses_from_keypoints
from demoforge.lib.task_library import get_task
from demoforge.schemas.core import (
    WrittenFile, column_numpy, file_sha256, get_schema, read_table, read_table_file, table_files, write_table,
)
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.llm_eval import query_scene, upsample
from demoforge.tasks.screening import screened_ids

POLICY_VERSION = "1"
POLICY_DIR = "_policy"  # checkpoints live beside the warehouse tables, like _prefect and _llm_cache
SCENE_KINDS = ("in_distribution", "out_of_distribution", "mirrored", "held_out")
_CHUNK = 2000  # episodes resampled at once (bounds memory: 2000 x 359 steps x 2 x 8 float64 = 92 MB)


def database_takes(warehouse: str, task: str) -> list[str]:
    """Takes with an episode database of the task."""
    t = read_table("episodes", warehouse, columns=["take"], task=task)
    return sorted(set(t.column("take").to_pylist()))


def database_inputs(warehouse: str, task: str, take: str) -> dict[str, Path]:
    """The database's files, as cache-key inputs: a re-augmented database retrains the policy."""
    files = {name: table_files(name, warehouse, task=task, take=take) for name in ("episodes", "episode_steps")}
    missing = [n for n, f in files.items() if not f]
    if missing:
        raise ValueError(f"no {' / '.join(missing)} of {task}/{take} in {warehouse}: "
                         f"run `demoforge augment` on the take first")
    return {n: Path(f[0]) for n, f in files.items()}


def load_policy_data(warehouse: str, task: str, take: str, n_waypoints: int = 20, robot_label: str | None = None):
    """(PolicyData of the valid episodes, the episodes table): every action sequence resampled to
    n_waypoints exactly as the prompts resample it. robot_label (an arm robot): only the episodes its
    screening lets through, and the original."""
    ep = read_table("episodes", warehouse, task=task, take=take).sort_by("episode_id")
    if ep.num_rows == 0:
        raise ValueError(f"no episodes of {task}/{take}: run `demoforge augment` on the take first")
    valid = np.asarray(ep.column("valid").to_numpy(zero_copy_only=False))
    if robot_label is not None:
        all_ids = np.asarray(ep.column("episode_id").to_numpy())
        original = np.asarray(ep.column("kind").to_pylist()) == "original"
        valid &= np.isin(all_ids, screened_ids(warehouse, task, take, robot_label)) | original
    if not valid.any():
        raise ValueError(f"no valid episode in {task}/{take}: the policy has nothing to learn from")
    ids = np.asarray(ep.column("episode_id").to_numpy())[valid]
    lengths = np.asarray(ep.column("length").to_numpy())[valid].astype(int)
    steps = read_table("episode_steps", warehouse, columns=["episode_id", "step", "action"], task=task, take=take)
    eid = np.asarray(steps.column("episode_id").to_numpy())
    # select and order in numpy: pyarrow 26.0.1 filters sliced nested fixed-size lists wrongly (zero-filled
    # actions here; see tests/schemas/test_core.py)
    keep = np.isin(eid, ids)
    order = np.lexsort((np.asarray(steps.column("step").to_numpy())[keep], eid[keep]))
    flat = steps.column("action").combine_chunks().flatten().flatten().to_numpy().reshape(-1, 2, 8)[keep][order]
    if len(flat) != lengths.sum():
        raise ValueError(f"{task}/{take}: episode_steps holds {len(flat)} steps of valid episodes, episodes.length "
                         f"says {lengths.sum()}: the database is incomplete, re-run `demoforge augment`")
    start = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    L = int(lengths.max())
    waypoints = np.empty((len(ids), n_waypoints, 2, 8))
    for a in range(0, len(ids), _CHUNK):
        b = min(a + _CHUNK, len(ids))
        step = np.minimum(np.arange(L)[None], lengths[a:b, None] - 1)  # pad by repeating the last step
        waypoints[a:b] = resample_batch(flat[start[a:b, None] + step], lengths[a:b], n_waypoints)
    data = PolicyData(ids, np.array(ep.column("kind").to_pylist())[valid],
                      np.asarray(ep.column("transform").to_pylist(), float)[valid],
                      column_numpy(ep, "object_keypoints")[valid], column_numpy(ep, "initial_poses")[valid], waypoints)
    return data, ep


@stage_task(name="policy_train", version=POLICY_VERSION, key_optional=("robot_label", "screening"))
def policy_train(task: str, take: str, warehouse: str, database: dict, seed: int = 0, epochs: int = 40,
                 max_seconds: float | None = 540.0, threads: int = 1, batch_size: int = 256, lr: float = 1e-3,
                 d_model: int = 64, layers: int = 2, val_fraction: float = 0.1, n_waypoints: int = 20,
                 robot_label: str | None = None, screening: Manifest | None = None) -> Manifest:
    """Train one policy on the valid episodes of task/take (robot_label, an arm robot: those its screening lets
    through; `screening`, that screening's manifest, keys the cache); write its checkpoint and a
    `policy_checkpoints` row.  Losses go to the run log every epoch; a progress bar of the steps (with
    the latest losses) is drawn when stderr is a terminal."""
    from prefect import get_run_logger
    from tqdm import tqdm

    # lazy: torch
    from demoforge.lib.policy.model import PolicyConfig
    from demoforge.lib.policy.train import TrainConfig, checkpoint_id, save_checkpoint, train_policy

    logger = get_run_logger()
    t0 = time.perf_counter()
    data, _ = load_policy_data(warehouse, task, take, n_waypoints, robot_label)
    load_s = time.perf_counter() - t0
    tr, va = split_by_placement(data, val_fraction, seed)
    logger.info("%s/%s: %d valid episodes -> %d train, %d validation (held-out placements), loaded in %.1f s",
                task, take, len(data), len(tr), len(va), load_s)
    pcfg = PolicyConfig(n_keypoints=data.keypoints.shape[1], n_waypoints=n_waypoints, d_model=d_model,
                        ff_dim=2 * d_model, enc_layers=layers, dec_layers=layers)
    tcfg = TrainConfig(epochs=epochs, batch_size=batch_size, lr=lr, max_seconds=max_seconds, threads=threads)
    bar = tqdm(total=None, desc=f"train-policy {task}", unit="step", mininterval=1.0, disable=None)

    def on_step(step, total):
        bar.total = total
        bar.update(1)

    def on_epoch(log):
        logger.info("epoch %d/%d: train loss %.5f, validation loss %.5f (%.0f s)", log.epoch + 1, epochs,
                    log.train_loss, log.val_loss, log.seconds)
        bar.set_postfix(train=f"{log.train_loss:.4f}", val=f"{log.val_loss:.4f}")

    try:
        res = train_policy(data.subset(tr), data.subset(va), seed, pcfg, tcfg, on_epoch=on_epoch, on_step=on_step)
    finally:
        bar.close()
    if res.stopped_early:
        logger.warning("time budget of %.0f s reached: stopped after %d of %d epochs", max_seconds,
                       len(res.history), epochs)
    cid = checkpoint_id(res.model)
    folder = Path(warehouse) / POLICY_DIR / task / take / cid
    meta = {"task": task, "take": take, "seed": seed, "n_train": res.n_train, "n_val": res.n_val,
            "val_fraction": val_fraction, "train_config": res.meta["train_config"], "val_metrics": res.val_metrics,
            "train_seconds": res.seconds, "epochs_run": len(res.history),
            "history": [[h.train_loss, h.val_loss] for h in res.history],
            "train_episode_ids": data.episode_id[tr].tolist()}
    pt, _ = save_checkpoint(res.model, folder, meta)
    m = res.val_metrics
    row = {"task": task, "take": take, "checkpoint_id": cid, "path": str(folder), "seed": seed,
           "n_params": sum(p.numel() for p in res.model.parameters()), "n_waypoints": n_waypoints,
           "n_train": res.n_train, "n_val": res.n_val, "epochs_requested": epochs, "epochs_run": len(res.history),
           "steps": res.steps, "threads": threads, "train_seconds": res.seconds, "load_seconds": load_s,
           "train_loss": res.history[-1].train_loss, "val_loss": float(m["loss"]),
           "val_pos_err_mm": float(m["pos_err_mm"]), "val_rot_err_deg": float(m["rot_err_deg"]),
           "val_grip_acc": float(m["grip_acc"]),
           "train_loss_history": [h.train_loss for h in res.history],
           "val_loss_history": [float(h.val_loss) for h in res.history],
           "config": json.dumps({"policy": pcfg.to_dict(), "train": res.meta["train_config"],
                                 "val_fraction": val_fraction}, sort_keys=True),
           "trained_at": datetime.now(timezone.utc)}
    logger.info("checkpoint %s: validation %.1f mm, %.2f deg, gripper %.3f; %d epochs in %.0f s on %d thread(s)",
                cid, m["pos_err_mm"], m["rot_err_deg"], m["grip_acc"], len(res.history), res.seconds, threads)
    written = write_table("policy_checkpoints", pa.Table.from_pylist([row], schema=get_schema("policy_checkpoints").arrow), warehouse)
    # the weights file belongs to the manifest: deleting it makes run_stage train again
    files = list(written) + [WrittenFile("policy_checkpoint_file", str(pt), 0, file_sha256(pt))]
    return Manifest.from_written("policy_checkpoints", files, path=written[0].path)


def checkpoint_row(manifest_or_path) -> dict:
    """The policy_checkpoints row a train manifest (or its table file) names."""
    path = manifest_or_path.path if isinstance(manifest_or_path, Manifest) else manifest_or_path
    rows = read_table_file("policy_checkpoints", path).to_pylist()
    if len(rows) != 1:
        raise ValueError(f"{path} should hold one checkpoint row, holds {len(rows)}")
    return rows[0]


def evaluation_scenes(task: str, seed: int, trials: int, original_kp: np.ndarray, box: np.ndarray,
                      kinds=SCENE_KINDS, held_out_keypoints: np.ndarray | None = None):
    """[(kind, trial, object poses, keypoints)]: in_distribution = the prompting evaluation's query
    scenes; mirrored = their mirror images; out_of_distribution = the original placement moved by
    an offset outside the augmentation's translation box; held_out = the given keypoints of
    database placements the policy was not trained on (validation episodes)."""
    spec = get_task(task)
    original = object_poses_from_keypoints(spec, original_kp)
    out = []
    for trial in range(trials):
        if "in_distribution" in kinds:
            poses, kp = query_scene(task, seed, trial)
            out.append(("in_distribution", trial, poses, kp))
        if "mirrored" in kinds:  # the same draw as query_scene, mirrored across x = 0
            placement = spec.sample_placement(np.random.default_rng([int(seed), 7919, int(trial)]), mirror=True)
            out.append(("mirrored", trial, placement.object_poses, spec.keypoints_world(placement.object_poses)))
        if "out_of_distribution" in kinds:
            poses = ood_placement(original, box, np.random.default_rng([int(seed), 4391, int(trial)]),
                                  spec.keypoints_world, spec.workspace)
            out.append(("out_of_distribution", trial, poses, spec.keypoints_world(poses)))
        if "held_out" in kinds and held_out_keypoints is not None and trial < len(held_out_keypoints):
            kp = held_out_keypoints[trial]
            out.append(("held_out", trial, object_poses_from_keypoints(spec, kp), kp))
    return out


def held_out_rows(checkpoint_path: str, episode_id: np.ndarray, kind: np.ndarray, valid: np.ndarray, n: int,
                  seed: int) -> np.ndarray:
    """Rows (into the episodes table) of n seeded valid episodes the checkpoint was not trained on."""
    cfg = json.loads((Path(checkpoint_path) / "config.json").read_text())
    trained = np.asarray(cfg.get("train_episode_ids", []), dtype=np.int64)
    rows = np.flatnonzero(valid & (kind != "original") & ~np.isin(episode_id, trained))
    rng = np.random.default_rng([int(seed), 2718])
    return np.sort(rng.choice(rows, size=min(n, len(rows)), replace=False)) if len(rows) else rows


@stage_task(name="policy_eval", version=POLICY_VERSION)
def policy_eval(task: str, take: str, warehouse: str, checkpoint: Manifest, trials: int = 10, seed: int = 0,
                kinds: list | tuple = SCENE_KINDS, threads: int = 1) -> list[Manifest]:
    """Predict, execute in MuJoCo and judge `trials` scenes of each kind; write `policy_trials` and,
    for the in-distribution scenes, `llm_trials` rows with strategy `policy` (Table 3 gains a row)."""
    import torch

    from demoforge.lib.policy.train import load_checkpoint  # lazy: torch

    bad = [k for k in kinds if k not in SCENE_KINDS]
    if bad:
        raise ValueError(f"unknown scene kind {bad}; choose from {', '.join(SCENE_KINDS)}")
    ck = checkpoint_row(checkpoint)
    model = load_checkpoint(ck["path"])
    cid, n_wp = ck["checkpoint_id"], model.config.n_waypoints
    ep = read_table("episodes", warehouse, task=task, take=take).sort_by("episode_id")
    kind = np.array(ep.column("kind").to_pylist())
    kp_all, init_all = column_numpy(ep, "object_keypoints"), column_numpy(ep, "initial_poses")
    length = np.asarray(ep.column("length").to_numpy())
    if not (kind == "original").any():
        raise ValueError(f"{task}/{take} has no original episode: re-run `demoforge augment`")
    o = np.flatnonzero(kind == "original")[0]
    m_row = np.flatnonzero(kind == "mirrored")[0] if (kind == "mirrored").any() else o
    augmented = kind != "original"
    box = translation_box(np.asarray(ep.column("transform").to_pylist(), float)[augmented]) if augmented.any() \
        else np.zeros((2, 2))
    held = held_out_rows(ck["path"], np.asarray(ep.column("episode_id").to_numpy()), kind,
                         np.asarray(ep.column("valid").to_numpy(zero_copy_only=False)), trials, seed) \
        if "held_out" in kinds else np.zeros(0, int)
    spec = get_task(task)
    original = object_poses_from_keypoints(spec, kp_all[o])
    original_m = MIRROR @ original @ MIRROR
    torch.set_num_threads(threads)
    model.predict(kp_all[o], init_all[o])  # warm-up: the first call pays one-off allocations
    rows, llm_rows = [], []
    for scene_kind, trial, poses, kp in evaluation_scenes(task, seed, trials, kp_all[o], box, kinds, kp_all[held]):
        # initial grippers and episode length: the database's, per layout (or the held-out episode's own)
        r = held[trial] if scene_kind == "held_out" else m_row if scene_kind == "mirrored" else o
        mirrored = kind[r] == "mirrored"
        t0 = time.perf_counter()
        pred = model.predict(kp, init_all[r])
        latency = time.perf_counter() - t0
        off = placement_offsets(original_m if mirrored else original, poses)
        result = execute(task, kp, upsample(pred, int(length[r])))
        row = {"task": task, "take": take, "checkpoint_id": cid, "scene_kind": scene_kind, "trial": trial,
               "seed": seed, "query_keypoints": np.asarray(kp).tolist(), "in_augmented_region": in_box(off, box),
               "max_offset_m": float(np.linalg.norm(off, axis=1).max()), "latency_ms": 1000 * latency,
               "predicted_waypoints": pred.tolist(), "success": bool(result.success),
               "failure_reason": "" if result.success else str(result.failure), "sim_detail": str(result.detail)}
        rows.append(row)
        if scene_kind == "in_distribution":
            llm_rows.append({"task": task, "take": take, "trial": trial, "strategy": "policy", "backend": "torch",
                             "model": cid, "seed": seed, "query_keypoints": row["query_keypoints"],
                             "retrieved_episode_ids": [], "n_waypoints": n_wp, "prompt_tokens": 0,
                             "answer_tokens": 0, "latency_s": latency, "cached": False, "parse_status": "ok",
                             "parse_detail": "", "success": row["success"], "failure_reason": row["failure_reason"],
                             "sim_detail": row["sim_detail"], "prompt_hash": "", "raw_answer": ""})
    out = [Manifest.from_written("policy_trials", write_table("policy_trials", pa.Table.from_pylist(rows, schema=get_schema("policy_trials").arrow), warehouse))]
    if llm_rows:
        out.append(Manifest.from_written("llm_trials", write_table("llm_trials", pa.Table.from_pylist(llm_rows, schema=get_schema("llm_trials").arrow), warehouse)))
    return out
