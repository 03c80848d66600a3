"""Hand keypoint and gripper metrics, as the thesis defines them (section 4.2).

All functions take arrays with any leading shape ``(..., J, D)`` (samples x joints x coords),
an optional boolean ``mask`` broadcastable to ``(..., J)`` (False = joint/hand not evaluated:
absent hand, invalid joint) and are NaN-safe: a joint counts only where the mask is True and both
prediction and ground truth are finite. Averages are over all counted (sample, joint) pairs --
the thesis's 1/(N x J) double sum; a result with nothing to count is NaN.

* :func:`mpjpe` -- eq. (4): mean Euclidean joint error (units of the input; m for 3D).
* :func:`pa_mpjpe` -- eq. (5): per sample, the prediction is aligned to the ground truth by the
  least-squares similarity (scale, rotation, translation; Umeyama, :func:`demoforge.lib.geometry.umeyama`)
  over that sample's counted joints, then MPJPE. Samples with fewer than 3 counted joints are
  skipped.
* :func:`root_relative_mpjpe` -- ARCTIC's convention: both skeletons translated so that the
  root (wrist, joint 0) is at the origin, then MPJPE (samples with an invalid root are skipped).
* :func:`mpjpe_2d` -- eq. (6): the same mean distance for 2D keypoints in pixels;
  :func:`mpjpe_2d_from_3d` projects camera-frame joints with K first (the thesis's procedure).
* :func:`pck` -- eq. (7): fraction of counted joints with 2D error < alpha * s_i. The thesis says
  s_i is "the size of the hand bounding box in image i" without defining it further; here
  s_i = max(width, height) of the tight axis-aligned box of sample i's ground-truth 2D joints
  (counted joints only). The comparison is strict (<), as in eq. (7).
* Gripper: position error (mm), geodesic orientation error (deg), approach-axis (gripper z)
  angle (deg), open/close accuracy.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.geometry import project_points as _project, quat_angle, quat_to_matrix, umeyama

__all__ = [
    "mean_of_finite",
    "joint_errors",
    "mpjpe",
    "pa_mpjpe",
    "procrustes_align",
    "root_relative_mpjpe",
    "mpjpe_2d",
    "mpjpe_2d_from_3d",
    "project_points",
    "bbox_size",
    "pck",
    "gripper_position_error_mm",
    "gripper_orientation_error_deg",
    "approach_axis_error_deg",
    "open_close_accuracy",
    "gripper_metrics",
    "keypoint_metrics",
]


def _valid(pred: np.ndarray, gt: np.ndarray, mask) -> np.ndarray:
    ok = np.isfinite(pred).all(-1) & np.isfinite(gt).all(-1)
    if mask is not None:
        ok = ok & np.broadcast_to(np.asarray(mask, dtype=bool), ok.shape)
    return ok


def _mean(err: np.ndarray, ok: np.ndarray) -> float:
    n = int(np.count_nonzero(ok))
    return float(np.sum(np.where(ok, err, 0.0)) / n) if n else float("nan")


def joint_errors(pred, gt, mask=None) -> np.ndarray:
    """Per-joint Euclidean errors (..., J), NaN where not counted."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    pred, gt = np.broadcast_arrays(pred, gt)
    ok = _valid(pred, gt, mask)
    with np.errstate(invalid="ignore"):
        e = np.linalg.norm(pred - gt, axis=-1)
    return np.where(ok, e, np.nan)


def mpjpe(pred, gt, mask=None) -> float:
    """Eq. (4): mean over counted (sample, joint) pairs of ||pred - gt||."""
    e = joint_errors(pred, gt, mask)
    return _mean(np.nan_to_num(e), np.isfinite(e))


def procrustes_align(pred, gt, mask=None) -> tuple[np.ndarray, np.ndarray]:
    """Similarity-align each sample of pred (..., J, 3) to gt over its counted joints.

    Returns (aligned (..., J, 3), ok_sample (...)): samples with < 3 counted joints (or a degenerate
    prediction) are NaN and ok_sample False.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    pred, gt = np.broadcast_arrays(pred, gt)
    ok = _valid(pred, gt, mask)
    batch = pred.shape[:-2]
    J = pred.shape[-2]
    P = pred.reshape(-1, J, 3)
    G = gt.reshape(-1, J, 3)
    O = ok.reshape(-1, J)
    w = O.astype(np.float64)
    Pz = np.where(O[..., None], P, 0.0)
    Gz = np.where(O[..., None], G, 0.0)
    # degenerate (coincident) predictions cannot be aligned: skip
    cnt = w.sum(-1)
    mu = (Pz * w[..., None]).sum(-2) / np.maximum(cnt, 1)[..., None]
    spread = (np.sum((Pz - mu[:, None]) ** 2, -1) * w).sum(-1)
    good = (cnt >= 3) & (spread > 1e-18)
    out = np.full(P.shape, np.nan)
    if good.any():
        s, R, t = umeyama(Pz[good], Gz[good], with_scale=True, weights=w[good])
        out[good] = s[:, None, None] * (Pz[good] @ np.swapaxes(R, -1, -2)) + t[:, None, :]
    return out.reshape(pred.shape), good.reshape(batch)


def pa_mpjpe(pred, gt, mask=None) -> float:
    """Eq. (5): MPJPE after per-sample Procrustes (similarity) alignment."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    aligned, good = procrustes_align(pred, gt, mask)
    ok = _valid(*np.broadcast_arrays(pred, gt), mask) & good[..., None]
    return mpjpe(aligned, gt, ok)


def root_relative_mpjpe(pred, gt, mask=None, root: int = 0) -> float:
    """MPJPE after subtracting each skeleton's root joint (ARCTIC: wrist = joint 0)."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    pred, gt = np.broadcast_arrays(pred, gt)
    ok = _valid(pred, gt, mask)
    ok = ok & ok[..., root:root + 1]
    return mpjpe(pred - pred[..., root:root + 1, :], gt - gt[..., root:root + 1, :], ok)


def mpjpe_2d(pred_px, gt_px, mask=None) -> float:
    """Eq. (6): mean pixel distance of 2D keypoints (..., J, 2)."""
    return mpjpe(pred_px, gt_px, mask)


def project_points(points_cam, K) -> np.ndarray:
    """Pinhole projection of camera-frame points (..., 3) -> (..., 2) px (NaN behind the camera)."""
    p = np.asarray(points_cam, dtype=np.float64)
    return np.where((p[..., 2:3] > 0), _project(p, K), np.nan)


def mpjpe_2d_from_3d(pred_cam, gt_cam, K, mask=None) -> float:
    """2D MPJPE of camera-frame 3D joints projected with K (the thesis's 4.2.2 procedure)."""
    return mpjpe_2d(project_points(pred_cam, K), project_points(gt_cam, K), mask)


def bbox_size(gt_px, mask=None) -> np.ndarray:
    """(...) max(width, height) of the tight box of each sample's counted GT 2D joints (NaN if none)."""
    g = np.asarray(gt_px, dtype=np.float64)
    ok = np.isfinite(g).all(-1)
    if mask is not None:
        ok = ok & np.broadcast_to(np.asarray(mask, dtype=bool), ok.shape)
    hi = np.max(np.where(ok[..., None], g, -np.inf), axis=-2)
    lo = np.min(np.where(ok[..., None], g, np.inf), axis=-2)
    with np.errstate(invalid="ignore"):
        s = np.max(hi - lo, axis=-1)
    return np.where(ok.any(-1), s, np.nan)


def pck(pred_px, gt_px, alpha: float, mask=None, box_size=None) -> float:
    """Eq. (7): fraction of counted joints with ||pred - gt|| < alpha * s_i (s_i: :func:`bbox_size`)."""
    pred_px = np.asarray(pred_px, dtype=np.float64)
    gt_px = np.asarray(gt_px, dtype=np.float64)
    pred_px, gt_px = np.broadcast_arrays(pred_px, gt_px)
    e = joint_errors(pred_px, gt_px, mask)
    s = bbox_size(gt_px, mask) if box_size is None else np.asarray(box_size, dtype=np.float64)
    ok = np.isfinite(e) & np.isfinite(s)[..., None]
    hit = ok & (np.nan_to_num(e, nan=np.inf) < alpha * np.nan_to_num(s, nan=0.0)[..., None])
    n = int(np.count_nonzero(ok))
    return float(np.count_nonzero(hit) / n) if n else float("nan")


# --------------------------------------------------------------------------- gripper


def _pose_ok(pred, gt, mask, n):
    ok = np.isfinite(pred[..., :n]).all(-1) & np.isfinite(gt[..., :n]).all(-1)
    if mask is not None:
        ok = ok & np.broadcast_to(np.asarray(mask, dtype=bool), ok.shape)
    return ok


def gripper_position_error_mm(pred, gt, mask=None) -> np.ndarray:
    """(...) position error in mm of (..., >=3) poses (NaN where not counted)."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    ok = _pose_ok(pred, gt, mask, 3)
    with np.errstate(invalid="ignore"):
        e = 1000.0 * np.linalg.norm(pred[..., :3] - gt[..., :3], axis=-1)
    return np.where(ok, e, np.nan)


def gripper_orientation_error_deg(pred, gt, mask=None) -> np.ndarray:
    """(...) geodesic angle (deg) between the quaternions pose[..., 3:7] (NaN where not counted)."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    ok = _pose_ok(pred, gt, mask, 7)
    qp = np.where(ok[..., None], pred[..., 3:7], [0, 0, 0, 1.0])
    qg = np.where(ok[..., None], gt[..., 3:7], [0, 0, 0, 1.0])
    return np.where(ok, np.degrees(quat_angle(qp, qg)), np.nan)


def approach_axis_error_deg(pred, gt, mask=None) -> np.ndarray:
    """(...) angle (deg) between the predicted and true approach axes (gripper z)."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    ok = _pose_ok(pred, gt, mask, 7)
    qp = np.where(ok[..., None], pred[..., 3:7], [0, 0, 0, 1.0])
    qg = np.where(ok[..., None], gt[..., 3:7], [0, 0, 0, 1.0])
    zp = quat_to_matrix(qp)[..., :, 2]
    zg = quat_to_matrix(qg)[..., :, 2]
    c = np.clip(np.sum(zp * zg, -1), -1.0, 1.0)
    return np.where(ok, np.degrees(np.arccos(c)), np.nan)


def open_close_accuracy(g_pred, g_gt, mask=None) -> float:
    """Fraction of counted frames whose open/closed state (g >= 0.5 open) matches."""
    gp = np.asarray(g_pred, dtype=np.float64)
    gg = np.asarray(g_gt, dtype=np.float64)
    ok = np.isfinite(gp) & np.isfinite(gg)
    if mask is not None:
        ok = ok & np.broadcast_to(np.asarray(mask, dtype=bool), ok.shape)
    n = int(np.count_nonzero(ok))
    return float(np.count_nonzero(ok & ((gp >= 0.5) == (gg >= 0.5))) / n) if n else float("nan")


def mean_of_finite(x) -> float:
    """The mean over the finite values of ``x``; NaN, without numpy's empty-slice warning, when there are none
    (a hand the detector never found has no gripper pose to measure)."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")


def gripper_metrics(pred8, gt8, mask=None) -> dict[str, float]:
    """Summary of (..., 8) gripper poses: mean/median position error (mm), orientation and
    approach-axis errors (deg), open/close accuracy."""
    pred8 = np.asarray(pred8, dtype=np.float64)
    gt8 = np.asarray(gt8, dtype=np.float64)
    pe = gripper_position_error_mm(pred8, gt8, mask)
    oe = gripper_orientation_error_deg(pred8, gt8, mask)
    ae = approach_axis_error_deg(pred8, gt8, mask)
    return {
        "position_error_mm": mean_of_finite(pe),
        "position_error_mm_median": float(np.nanmedian(pe)) if np.isfinite(pe).any() else float("nan"),
        "orientation_error_deg": mean_of_finite(oe),
        "orientation_error_deg_median": float(np.nanmedian(oe)) if np.isfinite(oe).any() else float("nan"),
        "approach_error_deg": mean_of_finite(ae),
        "open_close_accuracy": open_close_accuracy(pred8[..., 7], gt8[..., 7], mask),
    }


def keypoint_metrics(pred_cam, gt_cam, K=None, mask=None, pred_px=None, gt_px=None,
                     alphas=(0.05, 0.15)) -> dict[str, float]:
    """All keypoint metrics of section 4.2 for camera-frame joints (..., 21, 3).

    2D metrics use pred_px / gt_px when given, else the projections with K (thesis 4.2.2).
    """
    out = {
        "mpjpe_m": mpjpe(pred_cam, gt_cam, mask),
        "pa_mpjpe_m": pa_mpjpe(pred_cam, gt_cam, mask),
        "rr_mpjpe_m": root_relative_mpjpe(pred_cam, gt_cam, mask),
    }
    if pred_px is None and K is not None:
        pred_px = project_points(pred_cam, K)
    if gt_px is None and K is not None:
        gt_px = project_points(gt_cam, K)
    if pred_px is not None and gt_px is not None:
        out["mpjpe_2d_px"] = mpjpe_2d(pred_px, gt_px, mask)
        for a in alphas:
            out[f"pck@{a:g}"] = pck(pred_px, gt_px, a, mask)
    return out
