"""The Table 3 grid's query scenes (demoforge.lib.trajectories.query_scenes) under the two protocols. (The
knn_blend baseline: test_blend.py; the grid end to end: tests/flows/test_table3.py.)"""

import numpy as np
import pytest

from demoforge.lib.trajectories.augmentation import generate_episodes
from demoforge.lib.trajectories.query_scenes import (
    SAME_SCENE_MSE, augmentation_queries, covering_options, nearest_mse, placement_queries,
)
from tests.support.episodes import scripted_pouring_db


@pytest.fixture(scope="module")
def pouring_db():
    return scripted_pouring_db()


def test_thesis_queries_come_from_the_database_sampler_but_are_never_its_episodes(pouring_db):
    spec, src, db = pouring_db
    q = augmentation_queries(src, 12, seed=3, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert len(q) == 12 and q.keypoints.shape == (12, 11, 3)
    # never a database episode (same seed as the database: the held-out stream still differs)
    d = nearest_mse(q.keypoints, db.keypoints)
    assert np.all(d > SAME_SCENE_MSE) and np.allclose(d, q.nearest_mse)
    # the same distribution: parameters inside the database's box, plain and mirrored layouts both drawn
    lo, hi = db.params[1:].reshape(-1, 3).min(0), db.params[1:].reshape(-1, 3).max(0)
    assert np.all((q.params >= lo - 0.02) & (q.params <= hi + 0.02))
    assert 0 < q.mirrored.sum() < 12
    # its layout's initial grippers: the mirrored scenes start from the mirrored episodes' pose
    mir0 = db.initial[db.kind == "mirrored"][0]
    assert np.allclose(q.initial[q.mirrored], mir0) and np.allclose(q.initial[~q.mirrored], db.initial[0])
    # close to the database in keypoints (the database is dense), but not on it
    assert np.sqrt(d).max() < 0.05
    # deterministic from the seed, different for another seed
    again = augmentation_queries(src, 12, seed=3, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert np.array_equal(again.keypoints, q.keypoints)
    other = augmentation_queries(src, 12, seed=4, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert not np.allclose(other.keypoints, q.keypoints)


def test_a_query_that_is_a_database_episode_is_skipped(pouring_db):
    spec, src, db = pouring_db
    q = augmentation_queries(src, 3, seed=5, database_keypoints=db.keypoints)
    # a database that happens to contain the first two queries: the sampler must not return them
    db2 = np.concatenate([db.keypoints, q.keypoints[:2]])
    q2 = augmentation_queries(src, 3, seed=5, database_keypoints=db2)
    assert nearest_mse(q2.keypoints, db2).min() > SAME_SCENE_MSE
    assert np.array_equal(q2.keypoints[0], q.keypoints[2])


def test_novel_database_covers_the_placement_sampler(pouring_db):
    spec, src, db = pouring_db
    opts = covering_options(spec, src.keypoints, n_draws=1000)
    assert opts["independent"]
    wide = generate_episodes(src, n=300, n_mirrored=0, seed=0, **opts)
    q = placement_queries(spec, 20, seed=0, initial=db.initial[0], database_keypoints=wide.keypoints)
    # every placement's per-object offset from the demo lies inside the covering ranges
    from demoforge.lib.trajectories.augmentation import estimate_object_poses

    P0 = estimate_object_poses(src.keypoints, spec.keypoints_local, spec.keypoint_object)
    for poses, kp in zip(q.object_poses, q.keypoints):
        for o in range(2):
            d = kp[spec.keypoint_object == o, :2].mean(0) - src.keypoints[spec.keypoint_object == o, :2].mean(0)
            assert opts["translation_range"][0][0] <= d[0] <= opts["translation_range"][0][1]
            assert opts["translation_range"][1][0] <= d[1] <= opts["translation_range"][1][1]
            dyaw = np.angle(np.exp(1j * (np.arctan2(poses[o, 1, 0], poses[o, 0, 0]) - np.arctan2(P0[o, 1, 0], P0[o, 0, 0]))))
            assert opts["yaw_range"][0] <= dyaw <= opts["yaw_range"][1]
    assert not q.mirrored.any() and np.isfinite(q.nearest_mse).all()
