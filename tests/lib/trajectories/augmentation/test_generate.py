"""Augmentation: identity, mirror, object-relative skills, rotations, rejections, loop reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.trajectories import augmentation as au
from demoforge.lib import geometry as geo
from demoforge.lib.task_library import TASK_NAMES, get_task

_CACHE: dict = {}


def source(name: str, seed: int = 0, mirror: bool = False) -> au.DemoSource:
    key = (name, seed, mirror)
    if key not in _CACHE:
        t = get_task(name)
        _CACHE[key] = au.from_scripted_demo(t, t.scripted_demo(seed, mirror))
    return _CACHE[key]


def quat_close(a, b, atol=1e-9):
    return np.all(1.0 - np.abs(np.sum(a * b, axis=-1)) < atol)


@pytest.mark.parametrize("name", TASK_NAMES)
def test_identity_equals_original(name):
    src = source(name)
    out = au.execute_plan(src, au.make_plan(src), np.zeros((1, src.n_objects, 3)), np.zeros((1, src.n_objects, 2)))[0]
    np.testing.assert_allclose(out, src.trajectory, atol=1e-12)
    b = au.generate_episodes(src, n=20, n_mirrored=10, seed=0)
    assert b.kind[0] == "original" and b.valid[0]
    np.testing.assert_allclose(b.actions[0, :src.n_frames], src.trajectory, atol=1e-12)


@pytest.mark.parametrize("follow", [False, True])
def test_thesis_mode_identity_keeps_original_frames(follow):
    src = source("pouring")
    plan = au.make_plan(src, "thesis", n_transition=10, follow_objects=follow)
    out = au.execute_plan(src, plan, np.zeros((1, 2, 3)), np.zeros((1, 2, 2)))[0]
    for arm in range(2):
        keep = ~plan.inserted[:, arm]
        np.testing.assert_allclose(out[keep, arm], src.trajectory[plan.src[keep, arm], arm], atol=1e-12)
        # every original frame appears, in order
        assert np.array_equal(np.unique(plan.src[:, arm]), np.arange(src.n_frames))
        assert np.all(np.diff(plan.src[:, arm]) >= 0)


def test_mirror_twice_is_identity():
    src = source("mix_bowl")
    back = au.mirror_source(au.mirror_source(src))
    np.testing.assert_allclose(back.keypoints, src.keypoints, atol=1e-15)
    np.testing.assert_allclose(back.trajectory[..., :3], src.trajectory[..., :3], atol=1e-15)
    assert quat_close(back.trajectory[..., 3:7], src.trajectory[..., 3:7], 1e-12)
    assert [(s.arm, s.start, s.end, s.object) for s in back.segments] == [(s.arm, s.start, s.end, s.object) for s in src.segments]


@pytest.mark.parametrize("name", TASK_NAMES)
def test_mirror_matches_task_library_mirrored_demo(name):
    # By construction (base.mirror_demo): mirrored scripted demo of seed s = reflection of the plain one.
    plain, mirrored = source(name, 1), source(name, 1, True)
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
    b = au.generate_episodes(source("pouring"), n=50, n_mirrored=50, seed=2, yaw_range=(-0.6, 0.6), independent=True)
    q = b.actions[..., 3:7]
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    R = geo.quat_to_matrix(q.reshape(-1, 4))
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    R0 = geo.reflect_rotation(geo.quat_to_matrix(source("pouring").trajectory[..., 3:7]))
    np.testing.assert_allclose(np.linalg.det(R0), 1.0, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(-0.2, 0.2), dy=st.floats(-0.2, 0.2), dyaw=st.floats(-np.pi, np.pi),
       dx2=st.floats(-0.2, 0.2), dy2=st.floats(-0.2, 0.2), dyaw2=st.floats(-np.pi, np.pi),
       name=st.sampled_from(TASK_NAMES), mirror=st.booleans())
def test_skill_relative_pose_preserved(dx, dy, dyaw, dx2, dy2, dyaw2, name, mirror):
    src = source(name)
    if mirror:
        src = au.mirror_source(src)
    params = np.array([[[dx, dy, dyaw], [dx2, dy2, dyaw2]]])
    pivots = np.array([[[0.1, 0.2], [-0.1, 0.3]]])
    out = au.execute_plan(src, au.make_plan(src), params, pivots)[0]
    D = au.transform_matrices(params, pivots)[0]
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    P1 = D @ P0
    # the new object poses estimated from the new keypoints agree with D @ P0
    kp_new = au.transform_keypoints(src, params, pivots)[0]
    np.testing.assert_allclose(au.estimate_object_poses(kp_new, src.keypoints_local, src.keypoint_object), P1, atol=1e-9)
    T_old = geo.pose7_to_transform(src.trajectory[..., :7])
    T_new = geo.pose7_to_transform(out[..., :7])
    for s in src.segments:
        if s.kind != "skill" or s.object < 0:
            continue
        rel_old = geo.transform_inverse(P0[s.object]) @ T_old[s.start:s.end, s.arm]
        rel_new = geo.transform_inverse(P1[s.object]) @ T_new[s.start:s.end, s.arm]
        np.testing.assert_allclose(rel_new, rel_old, atol=1e-9)


def test_object_pose_from_keypoints_translation():
    src = source("trash_in_bin")
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    np.testing.assert_allclose(np.linalg.det(P0[:, :3, :3]), 1.0, atol=1e-12)
    np.testing.assert_allclose(au.estimate_object_poses(src.keypoints + [0.1, -0.05, 0], src.keypoints_local,
                                                        src.keypoint_object)[:, :3, 3] - P0[:, :3, 3],
                               [[0.1, -0.05, 0]] * 2, atol=1e-12)


def test_transform_demo_matches_generation():
    src = source("pouring")
    P0 = au.estimate_object_poses(src.keypoints, src.keypoints_local, src.keypoint_object)
    params = np.array([[[0.05, -0.04, 0.3], [-0.02, 0.06, -0.2]]])
    pivots = np.array([[[0.0, 0.25], [0.1, 0.3]]])
    D = au.transform_matrices(params, pivots)[0]
    a = au.transform_demo(src, D @ P0)
    b = au.execute_plan(src, au.make_plan(src), params, pivots)[0]
    np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("mode", ["object", "thesis"])
def test_vectorised_equals_loop(mode):
    src = source("empty_vase")
    plan = au.make_plan(src, mode, follow_objects=True)
    p = np.array([[0.05, -0.03, 0.3], [-0.02, 0.04, -2.0]])
    piv = np.array([[0.0, 0.2], [0.1, 0.3]])
    A = au.execute_plan(src, plan, p[None], piv[None])[0]
    B = au.transform_demo_loop(src, plan, p, piv)
    np.testing.assert_allclose(A[..., :3], B[..., :3], atol=1e-12)
    assert quat_close(A[..., 3:7], B[..., 3:7], 1e-12)
    np.testing.assert_array_equal(A[..., 7], B[..., 7])


def test_continuity_no_jumps():
    src = source("mix_bowl")
    b = au.generate_episodes(src, n=200, n_mirrored=100, seed=5, independent=True, yaw_range=(-0.5, 0.5))
    step = np.linalg.norm(np.diff(b.actions[..., :3], axis=1), axis=-1).max()
    step0 = np.linalg.norm(np.diff(src.trajectory[..., :3], axis=0), axis=-1).max()
    assert step < 3 * step0 + 0.01


def test_rejections_with_reason():
    src = source("pouring")
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
    src = source("trash_in_bin")
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
    src = source("open_container")  # the lid sits on the container: one group
    g = au.object_groups(src)
    assert g[0] == g[1]
    b = au.generate_episodes(src, n=50, n_mirrored=0, independent=True)
    np.testing.assert_array_equal(b.params[:, 0], b.params[:, 1])
    src = source("pouring")
    b = au.generate_episodes(src, n=50, n_mirrored=0, independent=True)
    assert not np.allclose(b.params[1:, 0], b.params[1:, 1])


def test_mirror_permutation_is_involution():
    for name in TASK_NAMES:
        t = get_task(name)
        p = au.mirror_permutation(t.keypoints_local, t.keypoint_object)
        np.testing.assert_array_equal(p[p], np.arange(len(p)))
        np.testing.assert_allclose(t.keypoints_local[p], t.keypoints_local * [-1, 1, 1], atol=1e-12)


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
