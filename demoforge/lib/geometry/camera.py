"""Pinhole camera: projecting camera-frame points to pixels and back-projecting pixels with depth.

K is the 3x3 intrinsic matrix; points are in the camera frame (z along the optical axis, metres).
"""

from __future__ import annotations

import numpy as np


def project_points(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pinhole projection of camera-frame points (..., 3) with intrinsics K (3, 3) -> pixels (..., 2).

    NaN in gives NaN out; points at z = 0 give inf/NaN (callers decide what is behind the camera)."""
    p = np.asarray(points_cam, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = p @ np.asarray(K, dtype=np.float64).T
        return uvw[..., :2] / uvw[..., 2:3]


def backproject(uv: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """X = z K^-1 [u, v, 1] for pixels uv (..., 2) and depth z (...) along the optical axis -> (..., 3)."""
    uv = np.asarray(uv, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    return np.stack([x * z, y * z, z], axis=-1)
