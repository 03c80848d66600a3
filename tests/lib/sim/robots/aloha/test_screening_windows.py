"""The screening's windows stage (lib/sim/robots/aloha/screening_windows.py): the bounds that spare hull
distances bracket the held-object scores, and the batched scores are the per-episode ones."""

from __future__ import annotations

import numpy as np

from demoforge.lib.sim.robots.aloha.screening_windows import _score_bounds, held_scores
from demoforge.lib.trajectories.segmentation import grasped_object_scores


def _objects(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two objects' keypoints (n, 11, 3) side by side and pinch points (n, 3), a quarter inside the first's hull."""
    rng = np.random.default_rng(seed)
    ko = np.array([0] * 5 + [1] * 6)
    kp = rng.uniform(-0.1, 0.1, (n, 11, 3)) + np.where(ko == 0, -0.15, 0.15)[None, :, None] * np.array([1, 0, 0])
    p = rng.uniform(-0.3, 0.3, (n, 3))
    p[:n // 4] = kp[:n // 4, ko == 0].mean(axis=1)
    return kp, ko, p


def test_the_batched_held_scores_are_the_per_episode_ones():
    """held_scores: segmentation.grasped_object_scores of each row, bit for bit (the held object is their argmin)."""
    kp, ko, p = _objects(5, 60)
    p = np.asarray(np.broadcast_to(p[:, None], (60, 2, 3))[:, 1])  # a strided view, as held_batch passes
    plain = np.array([grasped_object_scores(kp[e], ko, p[e]) for e in range(len(p))])
    assert np.array_equal(held_scores(kp, ko, p), plain)


def test_the_hull_score_bounds_hold():
    """held_batch's bounds of segmentation.grasped_object_scores (NNLS hull distance plus a tenth of the nearest
    keypoint's) bracket the scores: inside, beside and far from the objects."""
    rng = np.random.default_rng(3)
    ko = np.array([0] * 5 + [1] * 6)
    kp = rng.uniform(-0.1, 0.1, (40, 11, 3)) + np.where(ko == 0, -0.15, 0.15)[None, :, None] * np.array([1, 0, 0])
    p = rng.uniform(-0.3, 0.3, (40, 3))
    p[:10] = kp[:10, ko == 0].mean(axis=1)  # inside the first object's hull
    low, high = _score_bounds(kp, ko, p)
    scores = np.array([grasped_object_scores(kp[e], ko, p[e]) for e in range(len(p))])
    assert (low <= scores + 1e-12).all() and (scores <= high + 1e-12).all()
