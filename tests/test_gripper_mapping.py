"""Tests of lib.gripper_mapping: thesis pose mapping, open/close methods, smoothing."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lib.geometry import make_transform, quat_angle, quat_to_matrix, random_rotations
from lib.gripper_mapping import (
    GripperStateConfig, gripper_state, hand_to_gripper, mask_to_ranges, otsu_threshold,
    ranges_to_mask, smooth_poses, state_auto, to_pose8,
)
from lib.hand_model import hand_from_pinch, pinch_from_joints


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 100_000), st.floats(0.01, 0.13), st.sampled_from(["left", "right"]))
def test_mapping_recovers_pinch_frame(seed, aperture, side):
    rng = np.random.default_rng(seed)
    R = random_rotations(3, rng)
    T = make_transform(R, rng.uniform(-0.5, 0.5, (3, 3)))
    joints, _ = hand_from_pinch(T, np.full(3, aperture), side)
    pose7, d = hand_to_gripper(joints[:, None])
    np.testing.assert_allclose(pose7[:, 0, :3], T[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(d[:, 0], aperture, atol=1e-9)
    np.testing.assert_allclose(quat_to_matrix(pose7[:, 0, 3:]), R, atol=1e-7)
    # same frame as hand_model.pinch_from_joints
    Tp, _ = pinch_from_joints(joints)
    np.testing.assert_allclose(quat_to_matrix(pose7[:, 0, 3:]), Tp[:, :3, :3], atol=1e-9)


def test_thesis_rodrigues_fixes_the_approach_axis():
    j = np.zeros((1, 1, 21, 3))
    j[..., 0, :] = [0, 0, 0]
    j[..., 1, :] = [0, 0, 0]
    j[..., 4, :] = [-0.02, 0.0, 0.1]
    j[..., 8, :] = [0.02, 0.0, 0.1]
    pose7, d = hand_to_gripper(j)
    R = quat_to_matrix(pose7[0, 0, 3:])
    np.testing.assert_allclose(R[:, 2], [0, 0, 1], atol=1e-12)   # approach = base -> tips
    np.testing.assert_allclose(R[:, 0], [1, 0, 0], atol=1e-12)   # thumb -> index
    np.testing.assert_allclose(R[:, 1], [0, 1, 0], atol=1e-12)
    assert d[0, 0] == pytest.approx(0.04)


def test_degenerate_tips_borrow_previous_x_and_stay_finite():
    rng = np.random.default_rng(0)
    T = make_transform(random_rotations(4, rng), np.zeros((4, 3)))
    T[:] = T[0]
    joints, _ = hand_from_pinch(T, np.array([0.05, 0.0, 0.0, 0.05]), "right")
    joints[1:3, 4] = joints[1:3, 8]  # tips coincide exactly
    pose7, _ = hand_to_gripper(joints[:, None])
    assert np.isfinite(pose7).all()
    ang = quat_angle(pose7[1:3, 0, 3:], pose7[0:1, 0, 3:])
    assert np.all(np.degrees(ang) < 5.0)
    # a hand with NaN joints gives NaN, others unaffected
    j2 = joints.copy()
    j2[2] = np.nan
    p2, _ = hand_to_gripper(j2[:, None])
    assert np.isnan(p2[2]).all() and np.isfinite(p2[[0, 1, 3]]).all()


def test_to_pose8_and_threshold_and_manual():
    p7 = np.zeros((3, 2, 7))
    p7[..., 6] = 1
    d = np.array([[0.01, 0.08], [0.07, 0.02], [0.059, 0.06]])
    g = gripper_state(d, "threshold", w_gripper=0.06)
    np.testing.assert_array_equal(g, [[0, 1], [1, 0], [0, 1]])
    p8 = to_pose8(p7, g)
    assert p8.shape == (3, 2, 8) and (p8[..., 7] == g).all()
    gm = gripper_state(d, closed_ranges={"left": [[1, 3]], "right": []})
    np.testing.assert_array_equal(gm, [[1, 1], [0, 1], [0, 1]])
    assert mask_to_ranges(ranges_to_mask([[2, 5], [7, 9]], 10)) == [[2, 5], [7, 9]]


def test_otsu_threshold_two_clusters():
    x = np.r_[np.full(30, 0.01), np.full(70, 0.08)]
    thr, m0, m1 = otsu_threshold(x)
    assert 0.01 < thr < 0.08 and m0 == pytest.approx(0.01) and m1 == pytest.approx(0.08)


def _aperture_profile(rest, pre, grasp, n=(40, 8, 120, 8, 40)):
    """rest -> open wide (pre-grasp) -> close to the grasp width (held) -> open wide -> rest."""
    seg = [np.linspace(rest, pre, n[0]), np.linspace(pre, grasp, n[1]), np.full(n[2], grasp),
           np.linspace(grasp, pre, n[3]), np.linspace(pre, rest, n[4])]
    closed = np.r_[np.zeros(n[0] + n[1], bool), np.ones(n[2], bool), np.zeros(n[3] + n[4], bool)]
    return np.concatenate(seg), closed


@pytest.mark.parametrize("rest,pre,grasp", [(0.06, 0.12, 0.09), (0.06, 0.05, 0.01), (0.06, 0.10, 0.06)])
def test_auto_beats_single_threshold_across_objects(rest, pre, grasp):
    rng = np.random.default_rng(0)
    d0, c0 = _aperture_profile(rest, pre, grasp)
    d1, c1 = _aperture_profile(0.06, 0.05, 0.01)
    d = np.stack([d0, d1], 1) + rng.normal(0, 0.006, (len(d0), 2))
    closed = np.stack([c0, c1], 1)
    g = state_auto(d)
    acc = ((g == 0) == closed).mean()
    assert acc > 0.95
    if grasp >= 0.06:  # the thesis's failure: the held width is above a rest-level threshold
        assert ((gripper_state(d, "threshold") == 0) == closed)[:, 0].mean() < 0.8


def test_auto_no_grasp_stays_open_and_handles_nan():
    rng = np.random.default_rng(1)
    d = 0.06 + rng.normal(0, 0.004, (200, 2))
    d[50:55, 1] = np.nan
    g = state_auto(d)
    assert (g == 1).all()


def test_smooth_poses_keeps_transitions_sharp():
    T = 40
    rng = np.random.default_rng(2)
    p7 = np.zeros((T, 2, 7))
    p7[..., 6] = 1.0
    p7[:20, :, 0] = 0.0
    p7[20:, :, 0] = 1.0  # a jump exactly at a grasp instant
    p7[..., :3] += rng.normal(0, 0.001, (T, 2, 3))
    g = np.where(np.arange(T) < 20, 1.0, 0.0)[:, None].repeat(2, 1)
    s = smooth_poses(p7, g, window=7)
    assert np.abs(s[19, :, 0]).max() < 0.01 and np.abs(s[20, :, 0] - 1).max() < 0.01
    assert s[..., :3].std() <= p7[..., :3].std() + 1e-9
    np.testing.assert_allclose(np.linalg.norm(s[..., 3:], axis=-1), 1.0)
    assert GripperStateConfig().w_gripper == 0.06
