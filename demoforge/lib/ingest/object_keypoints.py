"""Object keypoints: 2D annotation (pixels on one frame) + depth -> world-frame 3D points.

Each annotated pixel's depth is read robustly (median of the valid pixels of a small window,
:func:`demoforge.lib.ingest.alignment.read_depth_robust`), back-projected with ``X = Z K^-1 [u, v, 1]`` into the
OpenCV camera frame and mapped to the world (table) frame with ``T_world_camera``. A point whose
depth cannot be read is never guessed: it is NaN with ``valid`` False and a reason code
(:data:`REASONS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.ingest.alignment import backproject, read_depth_robust
from demoforge.lib.geometry import transform_points

__all__ = ["REASONS", "KeypointBackprojection", "backproject_keypoints", "backproject_keypoints_detailed"]

#: Reason codes for invalid points.
REASONS = {
    0: "ok",
    1: "uv not finite",
    2: "outside the image",
    3: "no valid depth in the window",
}


@dataclass
class KeypointBackprojection:
    points_world: np.ndarray   # (K, 3), NaN where invalid
    points_camera: np.ndarray  # (K, 3), NaN where invalid
    valid: np.ndarray          # (K,) bool
    depth: np.ndarray          # (K,) robust depth (m), NaN where invalid
    n_valid_pixels: np.ndarray  # (K,) valid depth pixels in the window
    reason: np.ndarray         # (K,) int code of REASONS

    @property
    def reasons(self) -> list[str]:
        return [REASONS[int(r)] for r in self.reason]


def backproject_keypoints_detailed(uv, depth, K, T_world_camera, window: int = 5,
                                   min_valid: int = 3, depth_scale: float = 1.0) -> KeypointBackprojection:
    """Like :func:`backproject_keypoints`, with camera points, depths and reason codes.

    ``depth`` (H, W) in metres (0/NaN invalid); for a uint16 millimetre image pass
    ``depth_scale=0.001``.
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[-1] != 2:
        raise ValueError(f"uv must be (K, 2), got {uv.shape}")
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got {d.shape}")
    if depth_scale != 1.0 or not np.issubdtype(d.dtype, np.floating):
        d = d.astype(np.float64) * depth_scale
    H, W = d.shape
    z, n = read_depth_robust(d, uv, window=window, min_valid=min_valid)
    finite = np.isfinite(uv).all(-1)
    inside = finite & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
    valid = inside & np.isfinite(z)
    reason = np.where(~finite, 1, np.where(~inside, 2, np.where(~np.isfinite(z), 3, 0)))
    pc = backproject(np.where(finite[:, None], uv, 0.0), np.where(valid, z, np.nan), K)
    pc = np.where(valid[:, None], pc, np.nan)
    pw = transform_points(np.asarray(T_world_camera, dtype=np.float64), np.where(valid[:, None], pc, 0.0))
    pw = np.where(valid[:, None], pw, np.nan)
    return KeypointBackprojection(points_world=pw, points_camera=pc, valid=valid,
                                  depth=np.where(valid, z, np.nan), n_valid_pixels=n, reason=reason)


def backproject_keypoints(uv, depth, K, T_world_camera, window: int = 5,
                          min_valid: int = 3, depth_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) pixels on one frame + its depth -> (points_world (K, 3), valid (K,) bool).

    Points with no valid depth (or uv outside the image / not finite) are NaN with valid False;
    :func:`backproject_keypoints_detailed` gives the reason per point.
    """
    r = backproject_keypoints_detailed(uv, depth, K, T_world_camera, window, min_valid, depth_scale)
    return r.points_world, r.valid
