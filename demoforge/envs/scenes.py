"""The scenes an environment resets to, under the evaluation's two protocols
(demoforge.lib.trajectories.query_scenes, reused as it is; no warehouse needed).

* ``thesis``: a scene from the augmentation sampler of a database built from a demonstration (the
  thesis's 5.3.1; augmentation_queries: the database's distribution, a held-out seed stream, only draws
  the augmentation accepts, half of them mirrored by default as the thesis's databases). The
  demonstration: ``source`` (a DemoSource, e.g. demoforge.schemas.reads.demonstration.load_demo_source of
  an ingested take) or, by default, the task library's scripted demonstration ``demo_seed`` (0: the demonstration of
  the synthetic take ``synth_<task>_s0000`` that ``make evaluate`` builds its databases from, as scripted:
  without the ingest's noise). ``generation``: the database's generate_episodes options (default: the
  thesis's, as ``make evaluate`` uses them).
* ``novel``: the task library's placement sampler (Task.sample_placement: every object placed and turned
  independently), as placement_queries draws it; the grippers start at the demonstration's first pose.

Each draw takes its seed from the environment's random generator, so ``reset(seed=s)`` fixes the scene.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.trajectories.augmentation.source import DemoSource, from_scripted_demo
from demoforge.lib.trajectories.query_scenes import PROTOCOLS, augmentation_queries

_SOURCES: dict = {}


def scripted_source(task, demo_seed: int = 0) -> DemoSource:
    """The task library's scripted demonstration `demo_seed` of `task` as an augmentation source (cached)."""
    key = (task.name, int(demo_seed))
    if key not in _SOURCES:
        _SOURCES[key] = from_scripted_demo(task, task.scripted_demo(int(demo_seed)))
    return _SOURCES[key]


def draw_scene(task, protocol: str, rng: np.random.Generator, source: DemoSource | None = None,
               mirrored_fraction: float = 0.5, generation: dict | None = None) -> dict:
    """One scene: {object_poses (n_obj, 4, 4), keypoints (K, 3), initial (2, 8) the grippers' start pose,
    mirrored, protocol}."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
    src = source if source is not None else scripted_source(task)
    if protocol == "thesis":
        q = augmentation_queries(src, 1, int(rng.integers(2**31 - 1)), n_mirrored_fraction=mirrored_fraction,
                                 **(generation or {}))
        return {"object_poses": q.object_poses[0], "keypoints": q.keypoints[0], "initial": q.initial[0],
                "mirrored": bool(q.mirrored[0]), "protocol": protocol}
    poses = np.asarray(task.sample_placement(rng).object_poses, float)
    return {"object_poses": poses, "keypoints": task.keypoints_world(poses), "initial": src.trajectory[0].copy(),
            "mirrored": False, "protocol": protocol}


__all__ = ["PROTOCOLS", "draw_scene", "scripted_source"]
