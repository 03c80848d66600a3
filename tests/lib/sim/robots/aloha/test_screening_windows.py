"""The screening's windows stage (lib/sim/robots/aloha/screening_windows.py): the bounds that spare hull
distances bracket the held-object scores, and the batched scores, smoothing, rotations and proximity signal
are the per-episode ones."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.geometry import quat_to_matrix
from demoforge.lib.sim.robots.aloha import SMOOTH_SIGMA
from demoforge.lib.sim.robots.aloha.screening_windows import (_proximity_sq, _score_bounds, held_scores, norm_last, rotations,
                                                             smooth_batch)
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
from demoforge.lib.trajectories.keyframes import smooth_actions
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


def test_the_rotations_are_quat_to_matrix_of_the_normalised_quaternions():
    """rotations (a compiled loop) against lib/geometry's quat_to_matrix of the quaternions divided by norm_last's
    norm, bit for bit, on poses of any scale."""
    rng = np.random.default_rng(3)
    poses = rng.normal(size=(40, 50, 2, 8)) * rng.uniform(0.2, 5.0, (40, 50, 2, 1))
    q = poses[..., 3:7]
    got = rotations(poses)
    assert got.shape == (40, 50, 2, 3, 3)
    assert np.array_equal(got, quat_to_matrix(q / norm_last(q)[..., None]))


def test_the_proximity_signal_is_the_nearest_keypoint_or_the_held_objects_approach():
    """_proximity_sq against the squared distance written out step by step: the nearest keypoint of any object to
    the hand; while a run holds an object, its keypoints where the run starts in place of its own, and its
    keypoints' nearest approach to the other object's."""
    rng = np.random.default_rng(5)
    E, T, K = 3, 12, 7
    ko = np.array([0, 0, 0, 1, 1, 1, 1])
    traj = rng.normal(size=(E, T, 2, 8))
    kpt = rng.normal(size=(E, T, 3, K))
    held = np.full((T, 2), -1)
    held[2:5, 1], held[5:9, 1], held[9:, 1] = 0, 1, 0
    got = _proximity_sq(traj, kpt, ko, held, 1)
    for e in range(E):
        for t in range(T):
            h = held[t, 1]
            start = min(a for a in range(t + 1) if (held[a:t + 1, 1] == h).all()) if h >= 0 else t
            best = np.inf
            for k in range(K):
                src = start if ko[k] == h else t
                best = min(best, float(((kpt[e, src, :, k] - traj[e, t, 1, :3]) ** 2).sum()))
                if h >= 0 and ko[k] != h:
                    best = min(best, min(float(((kpt[e, t, :, i] - kpt[e, t, :, k]) ** 2).sum())
                                         for i in range(K) if ko[i] == h))
            assert np.isclose(got[e, t], best, rtol=1e-12, atol=0.0), (e, t)


def test_the_batched_smoothing_is_the_planners_bit_for_bit():
    """smooth_batch (one compiled loop: scipy's Gaussian weights, its symmetric correlation, the runs between the
    gripper's changes on their own) against keyframes.smooth_actions per episode, on a pouring database's group
    with its quaternions' signs flipped at random steps (hemisphere_continuous) and scaled (the normalisation)."""
    t = get_task("pouring")
    b = generate_episodes(from_scripted_demo(t, t.scripted_demo(0)), n=6, n_mirrored=0, seed=2, workers=1)
    actions = np.asarray(b.actions, float)[:, :int(np.min(b.lengths))]
    rng = np.random.default_rng(9)
    actions[..., 3:7] *= np.where(rng.random(actions.shape[:3] + (1,)) < 0.2, -1.0, 1.0) * rng.uniform(0.5, 2.0)
    got = smooth_batch(actions, SMOOTH_SIGMA)
    assert (np.diff(actions[0, :, :, 7] >= 0.5, axis=0) != 0).any()  # gripper changes: several runs
    for e in range(len(actions)):
        assert np.array_equal(got[e], smooth_actions(actions[e], SMOOTH_SIGMA)), e


def test_a_quaternion_without_length_is_one_clear_error():
    """A pose whose quaternion is zero (or not finite) stops the smoothing with a ValueError that names it, as
    lib/geometry's quat_normalize does, instead of a division by zero in the kernel or NaN poses."""
    t = get_task("pouring")
    b = generate_episodes(from_scripted_demo(t, t.scripted_demo(0)), n=2, n_mirrored=0, seed=2, workers=1)
    actions = np.asarray(b.actions, float)[:, :int(np.min(b.lengths))]
    actions[1, 40, 0, 3:7] = 0.0
    actions[2, 7, 1, 4] = np.nan
    with pytest.raises(ValueError, match=r"2 quaternion\(s\) have zero norm or non-finite values \(the first: "
                                         r"episode 1, step 40, arm 0\)"):
        smooth_batch(actions, SMOOTH_SIGMA)
