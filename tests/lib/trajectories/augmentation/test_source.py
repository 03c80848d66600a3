"""The augmentation's demonstration source (demoforge.lib.trajectories.augmentation.source): object poses
estimated from keypoints, exact for a translation and for the whisk's collinear keypoints at any yaw."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories import augmentation as au
from tests.support.episodes import scripted_source


def test_object_pose_from_keypoints_translation():
    src = scripted_source("trash_in_bin")
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    np.testing.assert_allclose(np.linalg.det(P0[:, :3, :3]), 1.0, atol=1e-12)
    np.testing.assert_allclose(au.estimate_object_poses(src.keypoints + [0.1, -0.05, 0], src.keypoints_local,
                                                        src.keypoint_object)[:, :3, 3] - P0[:, :3, 3],
                               [[0.1, -0.05, 0]] * 2, atol=1e-12)


@pytest.mark.parametrize("yaw", [-2.5, -0.3, 0.0, 0.7, 3.0])
def test_collinear_whisk_pose_recovered_from_keypoints_for_any_yaw(yaw):
    """The whisk's keypoints lie on its axis; its pose (lying on the table) must still be exact."""
    task = get_task("mix_bowl")
    whisk = task.whisk_rest_pose(0.05, 0.3, yaw)
    poses = np.stack([whisk, task.sample_placement(np.random.default_rng(0)).object_poses[1]])
    kp = task.keypoints_world(poses)
    est = au.estimate_object_poses(kp, task.keypoints_local, task.keypoint_object)
    np.testing.assert_allclose(est[0], whisk, atol=1e-9)
    np.testing.assert_allclose(est[1], poses[1], atol=1e-9)
