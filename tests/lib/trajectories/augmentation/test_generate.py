"""Augmentation (demoforge.lib.trajectories.augmentation.generate, through the package): identity, mirror,
rotations, rejections, the loop reference, independent object groups. (Plans: test_plan.py; the source's object
poses: test_source.py; the mirror permutation: test_mirror.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib import geometry as geo
from demoforge.lib.task_library import TASK_NAMES
from demoforge.lib.trajectories import augmentation as au
from tests.support.episodes import scripted_source


def quat_close(a, b, atol=1e-9):
    return np.all(1.0 - np.abs(np.sum(a * b, axis=-1)) < atol)


@pytest.mark.parametrize("name", TASK_NAMES)
def test_identity_equals_original(name):
    src = scripted_source(name)
    out = au.execute_plan(src, au.make_plan(src), np.zeros((1, src.n_objects, 3)), np.zeros((1, src.n_objects, 2)))[0]
    np.testing.assert_allclose(out, src.trajectory, atol=1e-12)
    b = au.generate_episodes(src, n=20, n_mirrored=10, seed=0)
    assert b.kind[0] == "original" and b.valid[0]
    np.testing.assert_allclose(b.actions[0, :src.n_frames], src.trajectory, atol=1e-12)


def test_mirror_twice_is_identity():
    src = scripted_source("mix_bowl")
    back = au.mirror_source(au.mirror_source(src))
    np.testing.assert_allclose(back.keypoints, src.keypoints, atol=1e-15)
    np.testing.assert_allclose(back.trajectory[..., :3], src.trajectory[..., :3], atol=1e-15)
    assert quat_close(back.trajectory[..., 3:7], src.trajectory[..., 3:7], 1e-12)
    assert [(s.arm, s.start, s.end, s.object) for s in back.segments] == [(s.arm, s.start, s.end, s.object) for s in src.segments]


@pytest.mark.parametrize("name", TASK_NAMES)
def test_mirror_matches_task_library_mirrored_demo(name):
    # By construction (base.mirror_demo): mirrored scripted demo of seed s = reflection of the plain one.
    plain, mirrored = scripted_source(name, 1), scripted_source(name, 1, True)
    m = au.mirror_source(plain)
    np.testing.assert_allclose(m.trajectory[..., :3], mirrored.trajectory[..., :3], atol=1e-12)
    np.testing.assert_array_equal(m.trajectory[..., 7], mirrored.trajectory[..., 7])
    assert quat_close(m.trajectory[..., 3:7], mirrored.trajectory[..., 3:7])
    np.testing.assert_allclose(m.keypoints, mirrored.keypoints, atol=1e-12)
    np.testing.assert_array_equal(m.object_arm, mirrored.object_arm)
    # ... and the mirrored + translated episode equals the library's mirrored demo shifted
    b = au.generate_episodes(plain, n=4, n_mirrored=4, seed=3)
    d = b.params[1, 0, :2]
    shifted = mirrored.trajectory.copy()
    A = b.actions[1, :plain.n_frames]
    segs = [s for s in mirrored.segments if s.kind == "skill"]
    for s in segs:  # inside skills: exactly the library's mirrored demo + the scene shift
        np.testing.assert_allclose(A[s.start:s.end, s.arm, :2], shifted[s.start:s.end, s.arm, :2] + d, atol=1e-12)
    np.testing.assert_allclose(b.keypoints[1, :, :2], mirrored.keypoints[:, :2] + d, atol=1e-12)


def test_mirrored_rotations_valid():
    b = au.generate_episodes(scripted_source("pouring"), n=50, n_mirrored=50, seed=2, yaw_range=(-0.6, 0.6), independent=True)
    q = b.actions[..., 3:7]
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    R = geo.quat_to_matrix(q.reshape(-1, 4))
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    R0 = geo.reflect_rotation(geo.quat_to_matrix(scripted_source("pouring").trajectory[..., 3:7]))
    np.testing.assert_allclose(np.linalg.det(R0), 1.0, atol=1e-12)


def test_transform_demo_matches_generation():
    src = scripted_source("pouring")
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    params = np.array([[[0.05, -0.04, 0.3], [-0.02, 0.06, -0.2]]])
    pivots = np.array([[[0.0, 0.25], [0.1, 0.3]]])
    D = au.transform_matrices(params, pivots)[0]
    a = au.transform_demo(src, D @ P0)
    b = au.execute_plan(src, au.make_plan(src), params, pivots)[0]
    np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("mode", ["object", "thesis"])
def test_vectorised_equals_loop(mode):
    src = scripted_source("empty_vase")
    plan = au.make_plan(src, mode, follow_objects=True)
    p = np.array([[0.05, -0.03, 0.3], [-0.02, 0.04, -2.0]])
    piv = np.array([[0.0, 0.2], [0.1, 0.3]])
    A = au.execute_plan(src, plan, p[None], piv[None])[0]
    B = au.transform_demo_loop(src, plan, p, piv)
    np.testing.assert_allclose(A[..., :3], B[..., :3], atol=1e-12)
    assert quat_close(A[..., 3:7], B[..., 3:7], 1e-12)
    np.testing.assert_array_equal(A[..., 7], B[..., 7])


def test_continuity_no_jumps():
    src = scripted_source("mix_bowl")
    b = au.generate_episodes(src, n=200, n_mirrored=100, seed=5, independent=True, yaw_range=(-0.5, 0.5))
    step = np.linalg.norm(np.diff(b.actions[..., :3], axis=1), axis=-1).max()
    step0 = np.linalg.norm(np.diff(src.trajectory[..., :3], axis=0), axis=-1).max()
    assert step < 3 * step0 + 0.01


def test_rejections_with_reason():
    src = scripted_source("pouring")
    # a small workspace box: everything leaves it
    b = au.generate_episodes(src, n=10, n_mirrored=5, seed=0, workspace=[[-0.1, -0.1, 0], [0.1, 0.1, 0.3]])
    assert not b.valid.any() and set(b.reject_reason) == {"left_workspace"}
    # a huge safety distance: grippers too close
    b = au.generate_episodes(src, n=10, n_mirrored=5, seed=0, safety_distance=10.0,
                             workspace=[[-9, -9, -9], [9, 9, 9]])
    assert set(b.reject_reason) == {"grippers_too_close"}
    # default: original valid, reasons from the known set, counts consistent
    b = au.generate_episodes(src, n=300, n_mirrored=150, seed=0)
    assert b.valid[0] and set(b.reject_reason) <= set(au.REJECT_REASONS)
    assert np.array_equal(b.valid, b.reject_reason == "")
    # a constructed case: a shift pushing the scene off the far edge of the table
    far = au.generate_episodes(src, n=4, n_mirrored=0, seed=0, translation_range=((0, 0), (0.5, 0.5)))
    assert list(far.reject_reason[1:]) == ["left_workspace"] * 4
    # independent placements onto the same spot: objects overlap
    ov = au.generate_episodes(src, n=4, n_mirrored=0, seed=0, independent=True, min_object_distance=5.0,
                              workspace=[[-9, -9, -9], [9, 9, 9]])
    assert list(ov.reject_reason[1:]) == ["objects_overlap"] * 4


def test_batch_shapes_and_lazy_actions():
    src = scripted_source("trash_in_bin")
    b = au.generate_episodes(src, n=600, n_mirrored=300, seed=4)
    N = 601
    assert b.actions.shape == (N, b.n_steps_max, 2, 8) and b.keypoints.shape == (N, 11, 3)
    assert b.initial.shape == (N, 2, 8) and b.lengths.shape == (N,)
    assert (b.kind == "mirrored").sum() == 300 and (b.kind == "translated").sum() == 300
    np.testing.assert_array_equal(b.initial, b.actions[:, 0])
    np.testing.assert_array_equal(b.episode_actions([3, 500]), b.actions[[3, 500]])
    m = au.generate_episodes(src, n=600, n_mirrored=300, seed=4, materialize=True, workers=1)
    np.testing.assert_array_equal(m.actions, b.actions)
    np.testing.assert_array_equal(m.valid, b.valid)
    # reproducible from the seed
    c = au.generate_episodes(src, n=600, n_mirrored=300, seed=4)
    np.testing.assert_array_equal(c.params, b.params)


def test_independent_groups_stacked_objects():
    src = scripted_source("open_container")  # the lid sits on the container: one group
    g = au.object_groups(src)
    assert g[0] == g[1]
    b = au.generate_episodes(src, n=50, n_mirrored=0, independent=True)
    np.testing.assert_array_equal(b.params[:, 0], b.params[:, 1])
    src = scripted_source("pouring")
    b = au.generate_episodes(src, n=50, n_mirrored=0, independent=True)
    assert not np.allclose(b.params[1:, 0], b.params[1:, 1])
