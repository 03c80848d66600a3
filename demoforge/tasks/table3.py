"""Prefect task of the Table 3 grid: one (protocol, take, strategy) cell over its query scenes ->
predictions -> MuJoCo success check -> `table3_trials` rows."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.llm import get_backend
from demoforge.lib.sim import execute, sim_options
from demoforge.lib.trajectories.augmentation import mirror_source, transform_demo
from demoforge.lib.trajectories.blend import knn_blend
from demoforge.lib.trajectories.retrieval import KeypointIndex, select_random
from demoforge.schemas.catalog import query
from demoforge.schemas.core import get_schema, write_table
from demoforge.schemas.reads.demonstration import load_demo_source
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.llm_eval import keyframe_settings, llm_predict, upsample
from demoforge.tasks.policy import checkpoint_row
from demoforge.tasks.screening import screened_ids

TABLE3_VERSION = "7"  # 2: examples ordered most similar last; keyframe prompts (n_waypoints None); 3: structured answers; 4: 3 Retrieved prompts hold their examples; 5: keyframes of the smoothed sequences, the default; 6: no all-zero quaternion; 7: no dead end in the decoder
LLM_STRATEGIES = ("single", "random", "retrieval")
FREE_STRATEGIES = ("replay_original", "replay_top1", "knn_blend", "transform_demo")
POLICY = "policy"
ALL_STRATEGIES = LLM_STRATEGIES + FREE_STRATEGIES + (POLICY,)
K_EXAMPLES = 3


def _database(warehouse: str, task: str, database: str, robot_label: str | None = None) -> dict:
    """The database's valid episodes (ids, kinds, keypoints, initial poses, lengths); with robot_label (an arm
    robot: `aloha+2f140`) only those its screening lets through (`episode_screening`), and the original."""
    ep = query("SELECT episode_id, kind, object_keypoints, initial_poses, length FROM episodes "
               "WHERE task = ? AND take = ? AND valid ORDER BY episode_id", warehouse, [task, database])
    if ep.num_rows == 0:
        raise ValueError(f"no valid episodes of {task}/{database}: build the database first (`demoforge table3` does)")
    kinds = np.array(ep.column("kind").to_pylist())
    if not (kinds == "original").any():
        raise ValueError(f"{task}/{database} has no original episode: re-run the augmentation")
    db = {"ids": np.asarray(ep.column("episode_id").to_numpy()), "kinds": kinds,
          "keypoints": np.asarray(ep.column("object_keypoints").to_pylist(), float),
          "initial": np.asarray(ep.column("initial_poses").to_pylist(), float),
          "length": np.asarray(ep.column("length").to_numpy())}
    if robot_label is not None:  # selected in numpy: pyarrow 26 filters nested fixed-size lists wrongly
        keep = np.isin(db["ids"], screened_ids(warehouse, task, database, robot_label)) | (kinds == "original")
        db = {k: v[keep] for k, v in db.items()}
    return db


def nearest_source(source, query_keypoints: np.ndarray):
    """The demonstration or its mirror image, whichever is nearer to the scene in keypoint MSE (the
    augmentation's two layouts), for transform_demo."""
    m = mirror_source(source)
    q = np.asarray(query_keypoints, float)
    return m if np.mean(np.sum((m.keypoints - q) ** 2, -1)) < np.mean(np.sum((source.keypoints - q) ** 2, -1)) \
        else source


@stage_task(name="table3_trials", version=TABLE3_VERSION,
            key_optional=("number_format", "keyframes", "robot", "gripper", "scene_key", "screening"))
def table3_trials(task: str, protocol: str, take: str, take_index: int, database: str, strategy: str, warehouse: str,
                  episodes: Manifest, scenes: list, seed: int = 0, backend: str = "local",
                  backend_options: dict | None = None, n_waypoints: int | None = None, precision: int = 3,
                  max_tokens: int | None = None, policy_checkpoint: Manifest | None = None,
                  show_progress: bool = True, structured: bool | None = None,
                  number_format: str | None = None, keyframes: tuple | None = None, robot: str | None = None,
                  gripper: str | None = None, scene_key: str | None = None,
                  screening: Manifest | None = None) -> Manifest:
    """Predict and judge every scene (dicts of QueryScenes.scene) of one strategy on one database.
    `episodes` (the database's manifest) makes a re-augmented database recompute the cell; LLM answers
    are cached by the backend, so a re-run after an interruption pays only the robot checks. `robot`,
    `gripper`: the robot that judges (None: the floating grippers, whose cells keep their cache keys;
    `scene_key`, another robot's scene fingerprint, is in the key only). An arm robot retrieves, blends and
    replays only the episodes its screening lets through (`screening`: that manifest, keying the cell)."""
    from tqdm import tqdm

    opt = sim_options(robot or "grippers", gripper)

    if strategy not in ALL_STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}; choose from {', '.join(ALL_STRATEGIES)}")
    db = _database(warehouse, task, database, None if opt.robot.name == "grippers" else opt.robot.label)
    index = KeypointIndex(db["keypoints"], ids=db["ids"])
    orig_row = int(np.flatnonzero(db["kinds"] == "original")[0])
    original = int(db["ids"][orig_row])
    source = load_demo_source(take, task, warehouse) if strategy in ("knn_blend", "transform_demo") else None
    llm, model, policy = None, "", None
    if strategy in LLM_STRATEGIES:
        llm = get_backend(backend, cache_dir=Path(warehouse) / "_llm_cache", **(backend_options or {}))
        model = str(getattr(llm, "model", "") or "")
    elif strategy == POLICY:
        from demoforge.lib.policy.train import load_checkpoint  # lazy: torch

        if policy_checkpoint is None:
            raise ValueError("strategy `policy` needs a trained checkpoint")
        ck = checkpoint_row(policy_checkpoint)
        policy, model = load_checkpoint(ck["path"]), ck["checkpoint_id"]
    rows = []
    for sc in tqdm(scenes, desc=f"{protocol} {take} {strategy}", unit="scene", leave=False,
                   disable=None if show_progress else True):
        kp = np.asarray(sc["keypoints"], float)
        poses = np.asarray(sc["object_poses"], float)
        init = np.asarray(sc["initial"], float)
        # the episode length of the scene's layout (plain and mirrored plans may differ)
        layout = db["kinds"] == ("mirrored" if sc["mirrored"] else "original")
        n_steps = int(db["length"][layout][0] if layout.any() else db["length"][orig_row])
        row = {"task": task, "protocol": protocol, "take": take, "take_index": int(take_index), "database": database,
               "scene": int(sc["scene"]), "seed": int(seed), "scene_mirrored": bool(sc["mirrored"]),
               "nearest_mse": float(sc["nearest_mse"]), "query_keypoints": kp.tolist(), "strategy": strategy,
               "backend": backend if llm else "torch" if policy is not None else "none", "model": model,
               "example_ids": [], "prompt_tokens": 0, "answer_tokens": 0, "latency_s": 0.0, "cached": False,
               "parse_status": "ok", "parse_detail": "", "prompt_hash": "", "raw_answer": ""}
        top = [int(i) for i in np.asarray(index.query(kp, k=K_EXAMPLES).ids).ravel()]
        t0 = time.perf_counter()
        actions = None
        if strategy == "single":
            ids = [original]
        elif strategy == "random":
            ids = [int(i) for i in select_random(db["ids"], K_EXAMPLES, seed=seed * 1000 + int(sc["scene"]))]
        elif strategy == "replay_original":
            ids = [original]
        elif strategy == "replay_top1":
            ids = top[:1]
        elif strategy in ("retrieval", "knn_blend"):  # the thesis's 3 retrieved examples / their blend
            ids = top
        else:
            ids = []
        row["example_ids"] = ids
        if strategy in LLM_STRATEGIES:
            acts = episode_actions(warehouse, task, database, ids)
            pos = {int(i): r for r, i in enumerate(db["ids"])}
            examples = [(db["keypoints"][pos[i]], db["initial"][pos[i]], acts[i]) for i in ids]
            actions, fields = llm_predict(llm, examples, kp, init, n_steps, n_waypoints=n_waypoints,
                                          precision=precision, max_tokens=max_tokens, seed=seed,
                                          structured=structured, number_format=number_format,
                                          keyframes=keyframe_settings(task, keyframes))
            row.update(fields)
        elif strategy in ("replay_original", "replay_top1"):
            actions = episode_actions(warehouse, task, database, ids)[ids[0]]
        elif strategy == "knn_blend":
            acts = episode_actions(warehouse, task, database, ids)
            pos = {int(i): r for r, i in enumerate(db["ids"])}
            actions = knn_blend(source, [(acts[i], db["keypoints"][pos[i]], db["kinds"][pos[i]] == "mirrored")
                                         for i in ids], poses)
        elif strategy == "transform_demo":
            actions = transform_demo(nearest_source(source, kp), poses)
        else:  # policy
            actions = upsample(policy.predict(kp, init), n_steps)
        if strategy not in LLM_STRATEGIES:
            row["latency_s"] = time.perf_counter() - t0
        row.pop("parse_detail", None)
        if actions is None:
            row.update(success=False, failure_reason=row["parse_status"],
                       sim_detail=str(fields.get("parse_detail", ""))[:500])
        else:
            result = execute(task, kp, actions, options=opt)
            row.update(success=bool(result.success), failure_reason="" if result.success else str(result.failure),
                       sim_detail=str(result.detail))
        rows.append({**row, "robot": opt.robot.name, "gripper": opt.robot.gripper_name})
    schema = get_schema("table3_trials").arrow
    variant = None if opt.robot.name == "grippers" else {"robot": opt.robot.name, "gripper": opt.robot.gripper_name}
    written = write_table("table3_trials", pa.Table.from_pylist(rows, schema=schema), warehouse, variant=variant)
    return Manifest.from_written("table3_trials", written)
