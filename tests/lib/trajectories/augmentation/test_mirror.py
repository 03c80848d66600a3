"""Mirroring the keypoints (demoforge.lib.trajectories.augmentation.mirror): the permutation is an involution
that maps each keypoint onto its reflection."""

from __future__ import annotations

import numpy as np

from demoforge.lib.task_library import TASK_NAMES, get_task
from demoforge.lib.trajectories import augmentation as au


def test_mirror_permutation_is_involution():
    for name in TASK_NAMES:
        t = get_task(name)
        p = au.mirror_permutation(t.keypoints_local, t.keypoint_object)
        np.testing.assert_array_equal(p[p], np.arange(len(p)))
        np.testing.assert_allclose(t.keypoints_local[p], t.keypoints_local * [-1, 1, 1], atol=1e-12)
