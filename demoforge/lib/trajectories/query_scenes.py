"""Query scenes of the prompting evaluation (thesis Table 3) under two protocols.

`thesis` (the thesis's 5.3.1: new scenes made "by using the same data augmentation method"): a query
scene is drawn from the very sampler that built the take's episode database
(demoforge.lib.trajectories.augmentation.generate_episodes with the database's options and mirrored fraction), with a
held-out seed stream, so it is in the database's distribution but never one of its episodes.
Drawn scenes the augmentation itself would reject (robot leaves the workspace, grippers too close,
objects overlapping) are skipped, as the database marks such episodes invalid; so is a draw whose
keypoints coincide with a database episode (probability zero for continuous draws; checked anyway).

`novel`: the task library's placement sampler (every object placed and turned independently), the
scenes the evaluation used before. A database meant to serve them must cover that distribution:
`covering_options` derives the augmentation options (per-object translation and yaw ranges around the
demonstration's placement) that reach every placement the sampler can draw.

Units: metres, radians; keypoints (K, 3) and object poses (n_obj, 4, 4) in the world (table) frame;
initial gripper poses (2, 8) `[x, y, z, qx, qy, qz, qw, g]` (docs/architecture.md, Conventions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.trajectories.augmentation import estimate_object_poses, generate_episodes
from demoforge.lib.trajectories.retrieval import KeypointIndex

PROTOCOLS = ("thesis", "novel")
# Entropy word of the held-out stream: the database uses default_rng(seed), the queries
# default_rng([seed, QUERY_STREAM, attempt]) -- a different SeedSequence, so different draws.
QUERY_STREAM = 0x51E7
# Seed words of the task library's placement draws (the `novel` protocol; the evaluation's
# historical query scenes, see tasks/llm_eval.query_scene).
PLACEMENT_STREAM = 7919
# A query whose keypoint MSE to a database episode is below this (m^2; 1e-12 m^2 = 1 micrometre RMS)
# counts as that episode.
SAME_SCENE_MSE = 1e-12


@dataclass
class QueryScenes:
    """n query scenes of one task."""
    keypoints: np.ndarray  # (n, K, 3) world, m
    object_poses: np.ndarray  # (n, n_obj, 4, 4) world
    initial: np.ndarray  # (n, 2, 8) the robot's initial gripper poses in this scene
    mirrored: np.ndarray  # (n,) bool: the scene is a mirror image of the demonstration's layout
    params: np.ndarray  # (n, n_obj, 3) [dx, dy, dyaw] of the draw (nan for `novel`)
    nearest_mse: np.ndarray  # (n,) keypoint MSE to the nearest database episode, m^2 (nan if no database)

    def __len__(self) -> int:
        return len(self.keypoints)

    def scene(self, i: int) -> dict:
        """Scene i as plain JSON-able lists (the form stage tasks take, and hash, as input)."""
        return {"scene": int(i), "keypoints": self.keypoints[i].tolist(),
                "object_poses": self.object_poses[i].tolist(), "initial": self.initial[i].tolist(),
                "mirrored": bool(self.mirrored[i]), "params": self.params[i].tolist(),
                "nearest_mse": float(self.nearest_mse[i])}


def nearest_mse(query_keypoints: np.ndarray, database_keypoints: np.ndarray) -> np.ndarray:
    """(n,) keypoint MSE of each query (n, K, 3) to its nearest database scene (N, K, 3) (the thesis's
    retrieval metric)."""
    q = np.asarray(query_keypoints, float)
    if len(q) == 0:
        return np.zeros(0)
    return KeypointIndex(np.asarray(database_keypoints, float)).query(q, k=1).mse[:, 0]


def augmentation_queries(source, n: int, seed: int, database_keypoints: np.ndarray | None = None,
                         n_mirrored_fraction: float = 0.5, max_attempts: int = 20, **options) -> QueryScenes:
    """n query scenes from the augmentation sampler of a database built by
    generate_episodes(source, n, round(n * n_mirrored_fraction), seed, **options): the same
    distribution, a held-out seed stream, only draws that the augmentation accepts as valid, never a
    scene within SAME_SCENE_MSE of a database episode (database_keypoints: (N, K, 3), all of them,
    valid or not). Plain and mirrored draws are shuffled together; the result depends only on the
    arguments."""
    if n < 0:
        raise ValueError(f"need n >= 0 query scenes, got {n}")
    if not 0.0 <= n_mirrored_fraction <= 1.0:
        raise ValueError(f"n_mirrored_fraction must be in [0, 1], got {n_mirrored_fraction}")
    db = None if database_keypoints is None else np.asarray(database_keypoints, float)
    got: list[tuple] = []
    for attempt in range(max_attempts):
        if len(got) >= n:
            break
        m = max(4 * (n - len(got)), 8)  # some draws are invalid: oversample
        batch = generate_episodes(source, n=m, n_mirrored=int(round(m * n_mirrored_fraction)),
                                  seed=[int(seed), QUERY_STREAM, attempt], **options)
        rows = np.flatnonzero(batch.valid & (batch.kind != "original"))  # row 0 is the demo itself
        rows = np.random.default_rng([int(seed), QUERY_STREAM, attempt, 1]).permutation(rows)
        kp = batch.keypoints[rows]
        mse = nearest_mse(kp, db) if db is not None and len(db) else np.full(len(rows), np.nan)
        for r, k, e in zip(rows, kp, mse):
            if np.isfinite(e) and e < SAME_SCENE_MSE:
                continue
            got.append((k, batch.initial[r], batch.kind[r] == "mirrored", batch.params[r], e))
            if len(got) == n:
                break
    if len(got) < n:
        raise ValueError(f"only {len(got)} of {n} valid query scenes in {max_attempts} attempts: the augmentation "
                         "rejects nearly every draw of these options (workspace, safety distance)")
    if n == 0:
        K = len(source.keypoints)
        return QueryScenes(np.zeros((0, K, 3)), np.zeros((0, source.n_objects, 4, 4)), np.zeros((0, 2, 8)),
                           np.zeros(0, bool), np.zeros((0, source.n_objects, 3)), np.zeros(0))
    kp = np.stack([g[0] for g in got])
    poses = estimate_object_poses(kp, source.keypoints_local, source.keypoint_object)
    return QueryScenes(kp, poses, np.stack([g[1] for g in got]), np.array([g[2] for g in got]),
                       np.stack([g[3] for g in got]), np.array([g[4] for g in got], float))


def placement_queries(task, n: int, seed: int, initial: np.ndarray,
                      database_keypoints: np.ndarray | None = None) -> QueryScenes:
    """n scenes from the task library's placement sampler (Task.sample_placement, each object placed
    and turned independently), drawn with default_rng([seed, PLACEMENT_STREAM, i]) for scene i;
    `initial` (2, 8): the robot's start pose (the demonstration's)."""
    poses = []
    for i in range(n):
        placement = task.sample_placement(np.random.default_rng([int(seed), PLACEMENT_STREAM, int(i)]))
        poses.append(np.asarray(placement.object_poses, float))
    n_obj = len(task.objects)
    poses = np.stack(poses) if poses else np.zeros((0, n_obj, 4, 4))
    kp = np.stack([task.keypoints_world(p) for p in poses]) if n else np.zeros((0, len(task.keypoints_local), 3))
    mse = nearest_mse(kp, database_keypoints) if database_keypoints is not None and n else np.full(n, np.nan)
    return QueryScenes(kp, poses, np.broadcast_to(np.asarray(initial, float), (n, 2, 8)).copy(),
                       np.zeros(n, bool), np.full((n, n_obj, 3), np.nan), np.asarray(mse, float))


def covering_options(task, source_keypoints: np.ndarray, n_draws: int = 4000, seed: int = 0,
                     margin: float = 0.01, yaw_margin: float = 0.02) -> dict:
    """generate_episodes options whose draws reach every placement of task.sample_placement from the
    demonstration's placement (source_keypoints (K, 3)): objects moved independently
    (independent=True: each object's yaw about its own keypoint centroid, then a shift of that
    centroid), with translation and yaw ranges spanning the offsets of n_draws sampled placements
    (plus a margin). Each range is shared by all objects (the augmentation draws every group from one
    box), so it is the union of the objects' ranges."""
    kl, ko = task.keypoints_local, task.keypoint_object
    src_kp = np.asarray(source_keypoints, float)
    P0 = estimate_object_poses(src_kp, kl, ko)
    c0 = np.stack([src_kp[ko == o, :2].mean(0) for o in range(P0.shape[0])])
    rng = np.random.default_rng([int(seed), PLACEMENT_STREAM, 0xC0])
    P = np.stack([np.asarray(task.sample_placement(rng).object_poses, float) for _ in range(n_draws)])
    Pk = P[:, ko]  # (n, K, 4, 4) pose of each keypoint's object
    kp = np.einsum("nkij,kj->nki", Pk[..., :3, :3], kl) + Pk[..., :3, 3]
    c = np.stack([kp[:, ko == o, :2].mean(1) for o in range(P0.shape[0])], axis=1)  # (n, n_obj, 2)
    d = (c - c0).reshape(-1, 2)
    yaw0 = np.arctan2(P0[:, 1, 0], P0[:, 0, 0])
    dyaw = np.angle(np.exp(1j * (np.arctan2(P[..., 1, 0], P[..., 0, 0]) - yaw0))).ravel()
    lo, hi = d.min(0) - margin, d.max(0) + margin
    return {"independent": True,
            "translation_range": [[float(lo[0]), float(hi[0])], [float(lo[1]), float(hi[1])]],
            "yaw_range": [float(dyaw.min() - yaw_margin), float(dyaw.max() + yaw_margin)]}


__all__ = ["PROTOCOLS", "QUERY_STREAM", "PLACEMENT_STREAM", "SAME_SCENE_MSE", "QueryScenes", "nearest_mse",
           "augmentation_queries", "placement_queries", "covering_options"]
