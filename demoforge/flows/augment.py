"""Flows: one ingested demonstration -> segments -> the task's episode database; retrieval over it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from prefect import flow

from demoforge.flows.ingest import check_demonstration, ingest_take
from demoforge.lib.annotate import annotation_status, not_annotated_message
from demoforge.lib.ingest.options import IngestOptions
from demoforge.lib.takes import TakeError, take_task_name
from demoforge.lib.takes.sources import take_root
from demoforge.lib.task_library import TASK_NAMES
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.lib.trajectories.retrieval import KeypointIndex, select_original, select_random
from demoforge.runtime.runners import run_flow
from demoforge.schemas.catalog import query
from demoforge.schemas.core import read_table_file
from demoforge.tasks.augment import augment_take, segment_take
from demoforge.tasks.common import Manifest, opened_take, run_stage
from demoforge.tasks.screening import code_files


@flow(name="augment-take")
def augment_take_flow(
    path: str,
    warehouse: str,
    task: str | None = None,
    augment: AugmentOptions | None = None,
    ingest: IngestOptions | None = None,
    manual_segments: dict | None = None,
    show_progress: bool = True,
    allow_untrusted_hands: bool = False,
    database: str | None = None,
    robot: str | None = None,
    gripper: str | None = None,
    redraw_rounds: int = 8,
) -> dict[str, Manifest | None]:
    """Ingest the take (cached), segment each arm, and generate the task's episodes from it.

    augment: how many episodes and how they are drawn (demoforge.lib.trajectories.augmentation.options.
    AugmentOptions; default: 10,000, half mirrored, seed 0, generate_episodes' defaults).
    ingest: the options of the ingest it builds on (demoforge.lib.ingest.options.IngestOptions). The
    ingest runs again with them (a cache hit when the take was ingested with the same ones): give the
    ones the take was ingested with, or its gripper poses are rewritten with these, so the episodes
    never silently come from another hand-to-gripper mapping than the take's own.
    allow_untrusted_hands: build the database even when a hand's trajectory is not trusted (the
    `hand_presence` table: too few tracked frames); without it such a take stops with a ValueError.
    manual_segments: {arm: [boundary frames]} overrides the automatic segmentation of that arm.
    database: the episodes' key in `episodes.take` (default: the take's id), to keep a second database
    of the same take.
    robot, gripper: an arm robot (aloha): the placements its arms cannot serve (its screening) are drawn again,
    up to redraw_rounds rounds (0: drawn as without a robot).
    """
    aug = augment or AugmentOptions()
    take_dir = take_root(path)
    ingested = run_flow(ingest_take, path, warehouse, task=task, options=ingest, show_progress=show_progress)
    if ingested["object_keypoints"] is None:  # the episodes are placed by the object keypoints
        raise TakeError(not_annotated_message(path, annotation_status(opened_take(take_dir)).detail))
    if not allow_untrusted_hands:
        require_trusted_hands(ingested["hand_presence"])
    common = dict(take_dir=take_dir, task=task, warehouse=warehouse,
                  grippers=ingested["gripper_poses"], objects=ingested["object_keypoints"])
    segments = run_stage(segment_take, warehouse, **common, manual=manual_segments)
    episodes = run_stage(augment_take, warehouse, **common, segments=segments, n=aug.n, n_mirrored=aug.n_mirrored,
                         seed=aug.seed, options=dict(aug.generation), **({"database": database} if database else {}),
                         **({"robot": robot, "gripper": gripper, "redraw_rounds": redraw_rounds,
                             "screening_code": code_files()} if robot is not None and redraw_rounds > 0 else {}))
    # the robot executing the demonstration every episode is built from: when it fails, so will the
    # episodes, and the user hears it at once instead of after a whole-database robot check
    demo_check = check_demonstration(take_dir, warehouse, task, take_task_name(opened_take(take_dir), task),
                                     ingested)
    return {**ingested, "segments": segments, "episodes": episodes, "demo_check": demo_check}


def require_trusted_hands(presence: Manifest) -> None:
    """Raise a one-line ValueError naming the take's untrusted hands (see the `hand_presence` table)."""
    rows = [r for f in presence.files for r in read_table_file("hand_presence", f).to_pylist()]
    bad = [r for r in rows if not r["trusted"]]
    if bad:
        what = "; ".join(f"the {r['hand']} hand: {r['reason']}" for r in bad)
        raise ValueError(f"take {bad[0]['take']}: no episode database from an untrusted hand ({what}); "
                         "pass --allow-untrusted-hands to build it anyway")


def read_scene(path: str | Path) -> dict:
    """A query scene: {"object_keypoints": 11 x 3 world m, "initial_poses": 2 x 8 (optional)}."""
    try:
        scene = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read the scene JSON: {e}") from None
    kp = np.asarray(scene.get("object_keypoints"), dtype=float)
    if kp.shape != (11, 3) or not np.isfinite(kp).all():
        raise ValueError(f"{path}: object_keypoints must be 11 x 3 finite numbers (world frame, m), "
                         f"got shape {kp.shape}")
    return {"object_keypoints": kp, "initial_poses": scene.get("initial_poses")}


def retrieve(warehouse: str, task: str, keypoints: np.ndarray, k: int = 3, strategy: str = "retrieval",
             metric: str = "mse", take: str | None = None, seed: int = 0) -> list[dict]:
    """Episodes for a scene: top-k by keypoint MSE (`retrieval`), k random valid ones (`random`), or
    the original demonstration (`single`). Only valid episodes are candidates."""
    import re

    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    if take is not None and not re.fullmatch(r"[A-Za-z0-9_.\-]+", take):
        raise ValueError(f"invalid take name {take!r}")
    t = query("SELECT take, episode_id, kind, object_keypoints FROM episodes WHERE task = ? AND valid "
              "AND (? IS NULL OR take = ?) ORDER BY take, episode_id", warehouse, [task, take, take])
    if t.num_rows == 0:
        raise ValueError(f"no valid episodes of task {task!r}{' from take ' + take if take else ''} in "
                         f"{warehouse}; run `demoforge augment` first")
    takes = np.array(t.column("take").to_pylist())
    ids = np.asarray(t.column("episode_id").to_numpy())
    kinds = np.array(t.column("kind").to_pylist())
    rows = np.arange(t.num_rows)
    mse = np.full(t.num_rows, np.nan)
    if strategy == "retrieval":
        kp = np.asarray(t.column("object_keypoints").to_pylist(), float)
        res = KeypointIndex(kp, ids=rows).query(np.asarray(keypoints, float), k=k, metric=metric)
        picked, mse_picked = np.asarray(res.ids).ravel(), np.asarray(res.mse).ravel()
        mse[picked] = mse_picked
        mirrored = dict(zip(picked.tolist(), np.asarray(res.mirrored).ravel().tolist()))
    elif strategy == "random":
        picked = select_random(rows, k, seed)
    elif strategy == "single":
        picked = select_original(rows, kinds)
    else:
        raise ValueError(f"unknown strategy {strategy!r}: retrieval, random or single")
    if strategy != "retrieval":
        mirrored = {}
    return [{"take": str(takes[r]), "episode_id": int(ids[r]), "kind": str(kinds[r]),
             "mse": None if np.isnan(mse[r]) else float(mse[r]), "matched_mirrored": bool(mirrored.get(r, False))}
            for r in np.atleast_1d(picked)]
