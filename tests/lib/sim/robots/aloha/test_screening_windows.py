"""The screening's windows stage (lib/sim/robots/aloha/screening_windows.py): the bounds that spare hull
distances bracket the held-object scores."""

from __future__ import annotations

import numpy as np

from demoforge.lib.sim.robots.aloha.screening_windows import _score_bounds
from demoforge.lib.trajectories.segmentation import grasped_object_scores


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
