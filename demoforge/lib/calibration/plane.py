"""The camera's pose from the table plane in the depth (no board): RANSAC (Open3D's ``segment_plane``)
on the depth's point cloud gives the table's normal, so z up and the camera's height; the origin and
the x/y axes come from two points on the table's robot-side edge (clicked on the annotate page: the
robot's left end first, then its right end; the origin is their midpoint), or, without them, from the
camera's forward direction (+y, the origin where the optical axis meets the table).

Plane: ``n . p + d = 0`` in camera coordinates (metres), ``n`` unit, oriented towards the camera, so
``d`` > 0 is the camera's height above the table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from demoforge.lib.errors import UserError


class CalibrationError(UserError):
    """The pose cannot be found from this take (no board in view, no table plane, bad clicks)."""


@dataclass
class TablePlane:
    normal: np.ndarray        # (3,) unit, camera frame, towards the camera (world +z)
    height_m: float           # the camera's height above the plane
    inlier_fraction: float    # of the valid depth points used
    points: int
    rms_m: float              # inliers' distance to the plane


def table_plane(depth: np.ndarray, K: np.ndarray, stride: int = 4, distance_m: float = 0.006,
                iterations: int = 2000, seed: int = 0) -> TablePlane:
    """The dominant plane of a depth map (metres, 0 = invalid; a median over frames hides moving hands).

    RANSAC (Open3D ``segment_plane``, seeded: the same depth gives the same plane) on every
    ``stride``-th pixel, then a least-squares fit to the inliers."""
    import open3d as o3d

    H, W = depth.shape
    v, u = np.mgrid[0:H:stride, 0:W:stride]
    z = depth[v, u]
    ok = np.isfinite(z) & (z > 0)
    if ok.sum() < 500:
        raise CalibrationError(f"too little valid depth to find the table plane ({int(ok.sum())} points); "
                               f"check the recording's depth")
    K = np.asarray(K, float)
    x = (u[ok] - K[0, 2]) / K[0, 0] * z[ok]
    y = (v[ok] - K[1, 2]) / K[1, 1] * z[ok]
    pts = np.stack([x, y, z[ok]], axis=1)
    o3d.utility.random.seed(seed)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, inliers = cloud.segment_plane(distance_threshold=distance_m, ransac_n=3, num_iterations=iterations)
    P = pts[np.asarray(inliers, int)]
    if len(P) < 0.2 * len(pts):
        raise CalibrationError(f"no dominant plane in the depth: the largest covers {len(P) / len(pts):.0%} of the "
                               f"points; the camera must see a good part of the table")
    c = P.mean(axis=0)
    n = np.linalg.svd(P - c, full_matrices=False)[2][2]
    d = -float(n @ c)
    if d < 0:
        n, d = -n, -d
    rms = float(np.sqrt(np.mean((P @ n + d) ** 2)))
    return TablePlane(normal=n, height_m=d, inlier_fraction=len(P) / len(pts), points=len(P), rms_m=rms)


def rays_on_plane(uv: np.ndarray, K: np.ndarray, normal: np.ndarray, d: float) -> np.ndarray:
    """Camera-frame points where the pixels' rays meet the plane ``n . p + d = 0``."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    K = np.asarray(K, float)
    rays = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))], axis=1)
    denom = rays @ normal
    if np.any(denom >= -1e-9):
        raise CalibrationError("a clicked point is above the horizon of the table plane; click on the table")
    return rays * (-d / denom)[:, None]


def frame_on_plane(normal: np.ndarray, d: float, edge_points: np.ndarray | None = None) -> np.ndarray:
    """T_world_camera (4x4) of the table frame on the plane: z = ``normal``; with ``edge_points`` (2, 3)
    (camera frame, the robot-side edge's left then right end) x runs from the first to the second and
    the origin is their midpoint; without, y is the camera's forward direction on the table and the
    origin where the optical axis meets it."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    if edge_points is not None:
        a, b = (np.asarray(p, float) - (np.asarray(p, float) @ n + d) * n for p in np.asarray(edge_points, float))
        x = b - a
        x = x - (x @ n) * n
        if np.linalg.norm(x) < 0.05:
            raise CalibrationError(f"the two edge points are {np.linalg.norm(x) * 100:.1f} cm apart; click the "
                                   f"table edge's two ends (at least 5 cm apart)")
        x /= np.linalg.norm(x)
        y = np.cross(n, x)
        origin = (a + b) / 2
    else:
        fwd = np.array([0.0, 0.0, 1.0])
        y = fwd - (fwd @ n) * n
        if np.linalg.norm(y) < 1e-3:
            raise CalibrationError("the camera looks straight down at the table: its forward direction gives no "
                                   "table axis; click the table's robot-side edge on the annotate page")
        y /= np.linalg.norm(y)
        x = np.cross(y, n)
        if abs(n[2]) < 1e-6:
            raise CalibrationError("the camera's optical axis never meets the table plane")
        origin = fwd * (-d / n[2])
    R_cw = np.stack([x, y, n], axis=1)       # world axes in camera coordinates
    T = np.eye(4)
    T[:3, :3] = R_cw.T
    T[:3, 3] = -R_cw.T @ origin
    return T


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> dict[str, float]:
    """Position (m) and rotation (deg) error of a camera pose; tilt (deg: the angle between the two
    table normals seen from the camera) and height (m) error, which the table plane alone determines."""
    R = np.asarray(T_est)[:3, :3].T @ np.asarray(T_true)[:3, :3]
    rot = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    up_est, up_true = np.asarray(T_est)[2, :3], np.asarray(T_true)[2, :3]   # world z in camera coordinates
    tilt = float(np.degrees(np.arccos(np.clip(up_est @ up_true, -1.0, 1.0))))
    return {"position_m": float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_true)[:3, 3])),
            "rotation_deg": rot, "tilt_deg": tilt,
            "height_m": float(abs(np.asarray(T_est)[2, 3] - np.asarray(T_true)[2, 3]))}


def median_depth(frames: Sequence[np.ndarray]) -> np.ndarray:
    """Per pixel the median of the valid depth over frames (0 where no frame has depth)."""
    stack = np.stack([np.where(f > 0, f, np.nan) for f in frames])
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            m = np.nanmedian(stack, axis=0)
    return np.nan_to_num(m, nan=0.0).astype(np.float32)
