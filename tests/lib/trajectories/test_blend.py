"""The knn_blend baseline (demoforge.lib.trajectories.blend): one neighbour carried to a scene is that scene's
episode; the average of trajectories."""

import numpy as np
import pytest

from tests.support.episodes import scripted_pouring_db


@pytest.fixture(scope="module")
def pouring_db():
    return scripted_pouring_db()


def test_knn_blend_of_one_neighbour_carries_it_exactly(pouring_db):
    """An episode carried to its own scene is itself; carried to another episode's scene it is that
    episode (both are the same demo moved by planar transforms), up to the motion blends' rounding."""
    from demoforge.lib.trajectories.augmentation import estimate_object_poses
    from demoforge.lib.trajectories.blend import average_trajectories, knn_blend

    spec, src, db = pouring_db
    a, b = [i for i in np.flatnonzero(db.valid & (db.kind == "translated"))[:2]]
    acts = db.episode_actions([a, b])
    pose_a = estimate_object_poses(db.keypoints[a], spec.keypoints_local, spec.keypoint_object)
    pose_b = estimate_object_poses(db.keypoints[b], spec.keypoints_local, spec.keypoint_object)
    same = knn_blend(src, [(acts[0], db.keypoints[a], False)], pose_a)
    assert np.allclose(same[..., :3], acts[0][..., :3], atol=1e-9)
    moved = knn_blend(src, [(acts[0], db.keypoints[a], False)], pose_b)
    assert np.abs(moved[..., :3] - acts[1][..., :3]).max() < 2e-3
    assert np.array_equal(moved[..., 7], acts[1][..., 7])
    avg = average_trajectories([acts[0], acts[0], acts[1]])
    assert np.allclose(np.linalg.norm(avg[..., 3:7], axis=-1), 1.0)
    assert np.allclose(avg[..., :3], (2 * acts[0][..., :3] + acts[1][..., :3]) / 3)
