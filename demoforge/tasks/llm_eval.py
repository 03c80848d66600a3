"""Prefect task of the prompting-strategy evaluation (thesis Table 3): query scenes -> prompts -> LLM
-> parsed actions -> MuJoCo success check, one call per (task, take, strategy, backend)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.geometry import interpolate_poses
from demoforge.lib.llm import Sampling, get_backend
from demoforge.lib.llm.prompting import build_prompt, order_by_similarity, parse_actions
from demoforge.lib.sim import execute
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import transform_demo
from demoforge.lib.trajectories.keyframes import KeyframeSettings, answer_times, decode_keyframes
from demoforge.lib.trajectories.retrieval import KeypointIndex, select_random
from demoforge.schemas.catalog import query
from demoforge.schemas.core import write_table
from demoforge.schemas.reads.demonstration import load_demo_source
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.tasks.common import Manifest, stage_task

LLM_EVAL_VERSION = "6"  # 2: examples ordered most similar last; keyframe prompts (n_waypoints None); 3: structured answers; 4: keyframes of the smoothed sequences, the default; 5: no all-zero quaternion; 6: no dead end in the decoder
LLM_STRATEGIES = ("single", "random", "retrieval")
BASELINES = ("replay_top1", "transform_demo")
K_EXAMPLES = 3


def query_scene(task: str, seed: int, trial: int) -> tuple[np.ndarray, np.ndarray]:
    """A new, seeded object placement of the task (not one of the database's samples): (poses, keypoints)."""
    spec = get_task(task)
    rng = np.random.default_rng([int(seed), 7919, int(trial)])
    placement = spec.sample_placement(rng)
    return placement.object_poses, spec.keypoints_world(placement.object_poses)


def upsample(waypoints: np.ndarray, n_steps: int) -> np.ndarray:
    """(n, 2, 8) waypoints spread over an episode of n_steps frames: positions cubic, rotations slerp,
    gripper state from the nearest waypoint (open/close instants stay sharp)."""
    n = len(waypoints)
    t_wp = np.linspace(0.0, 1.0, n)
    t = np.linspace(0.0, 1.0, n_steps)
    pos, quat = interpolate_poses(t_wp, waypoints[..., :3], waypoints[..., 3:7], t,
                                  position="cubic" if n >= 4 else "linear")
    g = waypoints[np.rint(t * (n - 1)).astype(int), :, 7:8]
    return np.concatenate([pos, quat, g], axis=-1)


def _episode_data(warehouse: str, task: str, take: str):
    ep = query("SELECT episode_id, kind, object_keypoints, initial_poses, length FROM episodes "
               "WHERE task = ? AND take = ? AND valid ORDER BY episode_id", warehouse, [task, take])
    if ep.num_rows == 0:
        raise ValueError(f"no valid episodes of {task}/{take}: run `demoforge augment` on the take first")
    return {"ids": np.asarray(ep.column("episode_id").to_numpy()),
            "kinds": np.array(ep.column("kind").to_pylist()),
            "keypoints": np.asarray(ep.column("object_keypoints").to_pylist(), float),
            "initial": np.asarray(ep.column("initial_poses").to_pylist(), float),
            "length": np.asarray(ep.column("length").to_numpy())}


@stage_task(name="llm_trials", version=LLM_EVAL_VERSION, key_optional=("number_format", "keyframes"))
def llm_trials(task: str, take: str, strategy: str, warehouse: str, episodes: Manifest | None = None,
               backend: str = "local", backend_options: dict | None = None, trials: int = 3, seed: int = 0,
               n_waypoints: int | None = None, precision: int = 3, max_tokens: int | None = None,
               temperature: float = 0.0, structured: bool | None = None, number_format: str | None = None,
               keyframes: tuple | None = None) -> Manifest:
    """`trials` query scenes for one strategy; every prediction is judged by the MuJoCo success check.
    `structured`: constrained answers (see llm_predict; None: on for the local backend). `keyframes`:
    (pos_tol_m, rot_tol_rad, smooth_sigma_steps) of keyframe prompts (None: the task's settings; the
    flows pass them, so a change of the task's settings is a change of the key)."""
    db = _episode_data(warehouse, task, take)
    index = KeypointIndex(db["keypoints"], ids=db["ids"])
    original = int(db["ids"][db["kinds"] == "original"][0])
    n_steps = int(db["length"][db["ids"] == original][0])
    init = db["initial"][db["ids"] == original][0]
    llm = None
    if strategy in LLM_STRATEGIES:
        llm = get_backend(backend, cache_dir=Path(warehouse) / "_llm_cache", **(backend_options or {}))
    rows = []
    for trial in range(trials):
        poses, kp = query_scene(task, seed, trial)
        row = {"task": task, "take": take, "trial": trial, "strategy": strategy,
               "backend": backend if llm else "none", "model": getattr(llm, "model", "") if llm else "",
               "seed": seed, "query_keypoints": kp.tolist(), "n_waypoints": int(n_waypoints or 0), "prompt_tokens": 0,
               "answer_tokens": 0, "latency_s": 0.0, "cached": False, "parse_status": "ok", "parse_detail": "",
               "prompt_hash": "", "raw_answer": ""}
        if strategy == "single":
            ids = [original]
        elif strategy == "random":
            ids = [int(i) for i in select_random(db["ids"], K_EXAMPLES, seed=seed * 1000 + trial)]
        else:  # retrieval and the replay baseline use the top-k by keypoint MSE
            ids = [int(i) for i in np.asarray(index.query(kp, k=K_EXAMPLES).ids).ravel()]
        row["retrieved_episode_ids"] = ids if strategy != "transform_demo" else [original]
        actions = None
        if strategy == "replay_top1":
            actions = episode_actions(warehouse, task, take, ids[:1])[ids[0]]
            row["retrieved_episode_ids"] = ids[:1]
        elif strategy == "transform_demo":
            actions = _transform_original(warehouse, task, take, poses)
        else:
            acts = episode_actions(warehouse, task, take, ids)
            examples = [(db["keypoints"][db["ids"] == i][0], db["initial"][db["ids"] == i][0], acts[i]) for i in ids]
            actions, fields = llm_predict(llm, examples, kp, init, n_steps, n_waypoints=n_waypoints, precision=precision,
                                          max_tokens=max_tokens, temperature=temperature, seed=seed,
                                          structured=structured, number_format=number_format,
                                          keyframes=keyframe_settings(task, keyframes))
            row.update(fields)
            if fields["parse_status"] == "llm_error":
                row.update(success=False, failure_reason="llm_error", sim_detail="")
                rows.append(row)
                continue
        if actions is None:
            row.update(success=False, failure_reason=row["parse_status"], sim_detail="")
        else:
            result = execute(task, kp, actions)
            row.update(success=bool(result.success), failure_reason="" if result.success else str(result.failure),
                       sim_detail=str(result.detail))
        rows.append(row)
    written = write_table("llm_trials", pa.Table.from_pylist(rows), warehouse)
    return Manifest.from_written("llm_trials", written)


def llm_predict(llm, examples, query_keypoints: np.ndarray, initial: np.ndarray, n_steps: int,
                n_waypoints: int | None = None, precision: int = 3, max_tokens: int | None = None,
                temperature: float = 0.0, seed: int = 0,
                structured: bool | None = None, number_format: str | None = None,
                keyframes=None) -> tuple[np.ndarray | None, dict]:
    """One LLM prediction: examples [(keypoints, initial poses, actions)] and the query -> prompt (the
    examples ordered with the most similar one last, next to the new input) -> the backend's answer ->
    parsed actions brought to n_steps (None when the answer does not parse), and the llm_trials fields
    of the trial (tokens, latency, cache, parse status, prompt hash, raw answer).  n_waypoints None:
    a keyframe prompt (``keyframes``: the task's KeyframeSettings), whose answer is decoded with the
    keyframe decoder on the most similar example's time curve; else uniform waypoints, upsampled.  A backend failure gives parse_status `llm_error`,
    never an exception.  `structured`: the answer is constrained to the action-list syntax with the
    prompt's waypoint count (demoforge.lib.llm.grammar); None: on for the local backend (the 270M
    model's free answers often do not parse), off for openai (servers differ in what they accept)."""
    examples = order_by_similarity(examples, query_keypoints)
    prompt = build_prompt(examples, query_keypoints, initial, n_waypoints=n_waypoints, precision=precision,
                          number_format=number_format, keyframes=keyframes)
    fields = {"prompt_hash": prompt.hash, "n_waypoints": int(prompt.n_waypoints), "prompt_tokens": 0, "answer_tokens": 0, "latency_s": 0.0, "cached": False,
              "raw_answer": "", "parse_status": "ok", "parse_detail": ""}
    sampling = Sampling(temperature=temperature, max_tokens=max_tokens or int(prompt.answer_tokens_estimate) or 2048,
                        seed=seed, stop=tuple(prompt.stop),
                        structured=(getattr(llm, "name", "") == "local") if structured is None else bool(structured))
    t0 = time.perf_counter()
    try:
        c = llm.complete(prompt, sampling)
    except Exception as e:  # noqa: BLE001 - a backend failure is a failed trial, never a crash
        fields.update(parse_status="llm_error", parse_detail=f"{type(e).__name__}: {e}"[:500],
                      latency_s=time.perf_counter() - t0)
        return None, fields
    fields.update(prompt_tokens=int(c.prompt_tokens or 0), answer_tokens=int(c.completion_tokens or 0),
                  latency_s=0.0 if c.cached else float(c.latency_s), cached=bool(c.cached), raw_answer=c.text)
    parsed = parse_actions(c.text, expected_waypoints=prompt.n_waypoints, prefix=prompt.answer_prefix)
    fields.update(parse_status=parsed.status, parse_detail=parsed.detail)
    if not parsed.ok:
        return None, fields
    return decode_answer(prompt, prompt.read_answer(parsed.actions), n_steps), fields


def keyframe_settings(task: str, given: tuple | None = None):
    """The KeyframeSettings of a stage's prompts: the given (pos_tol_m, rot_tol_rad, smooth_sigma_steps),
    else the task's own (demoforge.lib.task_library: Task.keyframes)."""
    return KeyframeSettings(*given) if given else get_task(task).keyframes


def keyframe_key(task: str, n_waypoints: int | None) -> tuple | None:
    """What the flows pass as a stage's ``keyframes``: the task's settings as a tuple for keyframe
    prompts (so the stage's cache key follows them), None for uniform prompts."""
    from dataclasses import astuple

    return astuple(keyframe_settings(task)) if n_waypoints is None else None


def decode_answer(prompt, answer: np.ndarray, n_steps: int) -> np.ndarray:
    """A parsed (n, 2, 8) answer as n_steps actions: keyframes decoded as the robot executor interpolates
    (on the last example's time curve), uniform waypoints upsampled."""
    if getattr(prompt, "encoding", "uniform") == "keyframes":
        return decode_keyframes(answer, answer_times(prompt.keyframe_times, len(answer), n_steps), n_steps)
    return upsample(answer, n_steps)


def _transform_original(warehouse: str, task: str, take: str, poses: np.ndarray) -> np.ndarray:
    """The LLM-free baseline: the original demonstration carried to the new scene by the augmentation transform."""
    return transform_demo(load_demo_source(take, task, warehouse), poses)
