"""Tests of demoforge.lib.evaluation.metrics against values computed by hand."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.geometry import quat_to_matrix, random_quaternions, random_rotations
from demoforge.lib.evaluation.metrics import (
    approach_axis_error_deg, bbox_size, gripper_metrics, gripper_orientation_error_deg,
    gripper_position_error_mm, keypoint_metrics, mpjpe, mpjpe_2d, mpjpe_2d_from_3d, open_close_accuracy,
    pa_mpjpe, pck, root_relative_mpjpe,
)


def test_mpjpe_by_hand_with_mask_and_nan():
    gt = np.zeros((2, 3, 3))
    pred = np.zeros((2, 3, 3))
    pred[0, 0] = [3, 4, 0]      # 5
    pred[0, 1] = [0, 0, 1]      # 1
    pred[1, 2] = [0, 2, 0]      # 2
    assert mpjpe(pred, gt) == pytest.approx(8 / 6)
    mask = np.array([[True, False, True], [True, True, True]])
    assert mpjpe(pred, gt, mask) == pytest.approx(7 / 5)
    pred[1, 2] = np.nan
    assert mpjpe(pred, gt) == pytest.approx(6 / 5)
    assert np.isnan(mpjpe(pred, gt, np.zeros((2, 3), bool)))


def test_root_relative_by_hand():
    gt = np.zeros((1, 3, 3))
    pred = np.array([[[1.0, 0, 0], [1.0, 0, 0], [1.0, 3, 4]]])
    # after subtracting the roots: errors 0, 0, 5
    assert root_relative_mpjpe(pred, gt) == pytest.approx(5 / 3)
    pred[0, 0] = np.nan  # invalid root: sample skipped
    assert np.isnan(root_relative_mpjpe(pred, gt))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 100_000), st.floats(0.2, 5.0))
def test_pa_mpjpe_zero_for_similarity(seed, s):
    rng = np.random.default_rng(seed)
    gt = rng.normal(size=(4, 21, 3))
    R = random_rotations(4, rng)
    t = rng.normal(size=(4, 1, 3))
    pred = s * gt @ np.swapaxes(R, -1, -2) + t
    assert pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-9)
    assert mpjpe(pred, gt) > 0.01
    # with masked joints and NaN in masked joints
    pred[:, 5] = np.nan
    assert pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-9)


def test_pa_mpjpe_by_hand():
    """Against an independent textbook Procrustes (centre, scale by Frobenius norms, SVD)."""
    gt = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    pred = gt.copy()
    pred[3, 2] = 1.5
    a, b = pred - pred.mean(0), gt - gt.mean(0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / np.sum(a * a)
    aligned = s * a @ R.T + gt.mean(0)
    ref = np.linalg.norm(aligned - gt, axis=1).mean()
    assert pa_mpjpe(pred[None], gt[None]) == pytest.approx(ref, rel=1e-9)
    assert np.isnan(pa_mpjpe(pred[None, :2], gt[None, :2]))  # < 3 joints: not counted


def test_2d_metrics_and_pck_by_hand():
    gt = np.array([[[0.0, 0.0], [100.0, 0.0], [0.0, 50.0], [100.0, 50.0]]])  # box 100 x 50 -> s = 100
    pred = gt + np.array([[[3.0, 4.0], [0.0, 6.0], [0.0, 4.0], [20.0, 0.0]]])  # errors 5, 6, 4, 20
    assert mpjpe_2d(pred, gt) == pytest.approx(35 / 4)
    assert bbox_size(gt)[0] == 100.0
    assert pck(pred, gt, 0.05) == pytest.approx(1 / 4)   # < 5 px: 4 only; 5 is not < 5
    assert pck(pred, gt, 0.051) == pytest.approx(2 / 4)  # 5 < 5.1
    assert pck(pred, gt, 0.061) == pytest.approx(3 / 4)
    assert pck(pred, gt, 0.25) == pytest.approx(1.0)
    mask = np.array([[True, True, True, False]])           # box from counted joints: 100 x 50
    assert pck(pred, gt, 0.05, mask) == pytest.approx(1 / 3)
    K = np.array([[100.0, 0, 0], [0, 100.0, 0], [0, 0, 1]])
    p3 = np.array([[[0.0, 0.0, 1.0]]])
    g3 = np.array([[[0.03, 0.04, 1.0]]])
    assert mpjpe_2d_from_3d(p3, g3, K) == pytest.approx(5.0)
    km = keypoint_metrics(p3.repeat(3, 1) + [[[0], [0.1], [0.2]]], g3.repeat(3, 1) + [[[0], [0.1], [0.2]]], K)
    assert set(km) >= {"mpjpe_m", "pa_mpjpe_m", "rr_mpjpe_m", "mpjpe_2d_px", "pck@0.05", "pck@0.15"}
    # every joint off by the same (-3, -4, 0) cm: 5 cm MPJPE, nothing left after alignment; in pixels
    # 5 cm at depth z is 500 / z px with f = 100 (joints at z = 1, 1.1, 1.2)
    assert km["mpjpe_m"] == pytest.approx(0.05) and km["rr_mpjpe_m"] == pytest.approx(0.0, abs=1e-12)
    assert km["pa_mpjpe_m"] == pytest.approx(0.0, abs=1e-9)
    assert km["mpjpe_2d_px"] == pytest.approx((5 + 5 / 1.1 + 5 / 1.2) / 3)


def test_gripper_metrics_by_hand():
    gt = np.zeros((2, 8))
    gt[:, 6] = 1.0
    gt[:, 7] = [1, 0]
    pred = gt.copy()
    pred[0, :3] = [0.003, 0.004, 0]
    # 90 deg about x: approach axis z -> -y (90 deg), geodesic 90 deg
    pred[1, 3:7] = [np.sin(np.pi / 4), 0, 0, np.cos(np.pi / 4)]
    pred[1, 7] = 1
    np.testing.assert_allclose(gripper_position_error_mm(pred, gt), [5.0, 0.0])
    np.testing.assert_allclose(gripper_orientation_error_deg(pred, gt), [0.0, 90.0], atol=1e-6)
    np.testing.assert_allclose(approach_axis_error_deg(pred, gt), [0.0, 90.0], atol=1e-6)
    # rotation about z (twist) leaves the approach axis
    q = np.array([0, 0, np.sin(np.pi / 8), np.cos(np.pi / 8)])
    p2 = gt.copy()
    p2[:, 3:7] = q
    np.testing.assert_allclose(approach_axis_error_deg(p2, gt), 0.0, atol=1e-6)
    np.testing.assert_allclose(gripper_orientation_error_deg(p2, gt), 45.0, atol=1e-6)
    assert open_close_accuracy(pred[:, 7], gt[:, 7]) == 0.5
    assert open_close_accuracy([1, 0, np.nan], [1, 1, 0]) == 0.5
    m = gripper_metrics(pred, gt)
    assert m["position_error_mm"] == pytest.approx(2.5) and m["open_close_accuracy"] == 0.5
    # quaternion sign does not matter
    qs = random_quaternions(5, 0)
    a = np.concatenate([np.zeros((5, 3)), qs, np.ones((5, 1))], 1)
    b = a.copy()
    b[:, 3:7] *= -1
    np.testing.assert_allclose(gripper_orientation_error_deg(a, b), 0.0, atol=1e-5)
    assert np.allclose(quat_to_matrix(qs), quat_to_matrix(-qs))


def test_mean_of_finite_is_nan_without_a_warning_when_nothing_is_finite():
    import warnings

    from demoforge.lib.evaluation.metrics import mean_of_finite

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "Mean of empty slice" would raise here
        assert np.isnan(mean_of_finite(np.full(5, np.nan))) and np.isnan(mean_of_finite([]))
        assert mean_of_finite([1.0, np.nan, 3.0]) == 2.0
