"""Episode databases the tests build without rendering or ingesting: a real augmentation of the task
library's scripted pouring demonstration, written with the warehouse's contracts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demoforge.schemas.core import write_table

TASK = "pouring"
TAKE = "synth_pouring_s0000"


def build_episode_warehouse(root: Path, n: int = 12, n_mirrored: int = 6, seed: int = 1, demo_seed: int = 0) -> dict:
    """episodes + episode_steps of a real augmentation of the scripted pouring demo, in ``root``."""
    from demoforge.lib.trajectories.augmentation import DemoSource, generate_episodes
    from demoforge.lib.task_library import get_task
    from demoforge.tasks.augment import episode_steps_columns, episodes_columns

    spec = get_task(TASK)
    demo = spec.scripted_demo(demo_seed)
    src = DemoSource(task=TASK, trajectory=demo.gripper_actions(), keypoints=demo.keypoints()[0],
                     keypoint_object=spec.keypoint_object, keypoints_local=spec.keypoints_local,
                     segments=demo.segments, object_arm=spec.object_arm(False), workspace=spec.workspace)
    batch = generate_episodes(src, n=n, n_mirrored=n_mirrored, seed=seed, workspace=spec.workspace, workers=1)
    write_table("episodes", episodes_columns(TASK, TAKE, seed, batch), root)
    write_table("episode_steps", episode_steps_columns(TASK, TAKE, batch), root)
    actions = {int(i): batch.actions[k, : batch.lengths[k]].astype(np.float32) for k, i in enumerate(batch.episode_id)}
    return {"actions": actions, "valid": dict(zip(batch.episode_id.tolist(), batch.valid.tolist())),
            "kind": dict(zip(batch.episode_id.tolist(), batch.kind.astype(str).tolist())),
            "keypoints": dict(zip(batch.episode_id.tolist(), batch.keypoints)), "demo": demo}


SCRIPTED_TAKE = "scripted_pouring_s0000"


def scripted_database(warehouse: Path, n: int = 48) -> None:
    """A pouring database from the task library's scripted demonstration (no rendering needed)."""
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
    from demoforge.lib.task_library import get_task
    from demoforge.tasks.augment import episode_steps_columns, episodes_columns

    spec = get_task("pouring")
    batch = generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=n, n_mirrored=n // 2, seed=1,
                              workspace=spec.workspace)
    write_table("episodes", episodes_columns("pouring", SCRIPTED_TAKE, 1, batch), warehouse)
    write_table("episode_steps", episode_steps_columns("pouring", SCRIPTED_TAKE, batch), warehouse)


def scripted_policy_data(n: int = 40, n_mirrored: int = 20, seed: int = 1, n_wp: int = 8) -> "PolicyData":
    """The policy's data from a real augmentation of the scripted pouring demonstration (waypoints resampled)."""
    from demoforge.lib.policy.data import PolicyData, resample_batch
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

    spec = get_task("pouring")
    batch = generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=n, n_mirrored=n_mirrored,
                              seed=seed, materialize=True)
    return PolicyData(batch.episode_id, batch.kind, batch.params, batch.keypoints, batch.initial,
                      resample_batch(batch.actions, batch.lengths, n_wp))


def scripted_pouring_db(demo_seed: int = 3, n: int = 400, n_mirrored: int = 200, seed: int = 3):
    """(task spec, DemoSource, EpisodeBatch) of a real augmentation of a scripted pouring demonstration."""
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

    spec = get_task("pouring")
    src = from_scripted_demo(spec, spec.scripted_demo(demo_seed))
    return spec, src, generate_episodes(src, n=n, n_mirrored=n_mirrored, seed=seed)


_SOURCES: dict = {}


def scripted_source(name: str, seed: int = 0, mirror: bool = False) -> "DemoSource":
    """The task library's scripted demonstration of ``name`` as the augmentation's DemoSource (cached)."""
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo

    key = (name, seed, mirror)
    if key not in _SOURCES:
        t = get_task(name)
        _SOURCES[key] = from_scripted_demo(t, t.scripted_demo(seed, mirror))
    return _SOURCES[key]

