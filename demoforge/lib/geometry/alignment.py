"""Point-set alignment: the least-squares similarity (Umeyama / Kabsch) and applying it.

umeyama fits dst ~ s R src + t to corresponding (..., N, 3) point sets, optionally weighted and without
scale; apply_similarity maps points through the result.  Conventions: the package docstring of demoforge.lib.geometry.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from demoforge.lib.geometry._checks import _as_float
from demoforge.lib.geometry.transforms import _apply_linear


def umeyama(
    src: ArrayLike, dst: ArrayLike, with_scale: bool = True, weights: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares similarity dst ~ s R src + t for (..., N, 3) point sets -> (s (...), R (..., 3, 3), t (..., 3)).

    Umeyama (1991) with the reflection correction (det R = +1 always); with_scale=False is Kabsch
    (s = 1).  Optional non-negative weights (..., N).  ValueError for N < 3, mismatched shapes,
    non-finite input, bad weights, or a degenerate source (all points coincident).
    """
    src = _as_float(src, "src", last=3)
    dst = _as_float(dst, "dst", last=3)
    if src.ndim < 2 or dst.ndim < 2:
        raise ValueError(f"umeyama: src and dst must have shape (..., N, 3), got {src.shape} and {dst.shape}")
    if src.shape[-2] != dst.shape[-2]:
        raise ValueError(f"umeyama: src has {src.shape[-2]} points but dst has {dst.shape[-2]}")
    n_pts = src.shape[-2]
    if n_pts < 3:
        raise ValueError(f"umeyama: need at least 3 point correspondences, got {n_pts}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("umeyama: src/dst contain non-finite values")
    src, dst = np.broadcast_arrays(src, dst)
    if weights is None:
        w = np.ones(src.shape[:-1])
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim < 1 or w.shape[-1] != n_pts:
            raise ValueError(f"umeyama: weights must have shape (..., {n_pts}), got {w.shape}")
        if not np.isfinite(w).all() or np.any(w < 0):
            raise ValueError("umeyama: weights must be finite and non-negative")
        w = np.broadcast_to(w, src.shape[:-1])
        if np.any(np.count_nonzero(w > 0, axis=-1) < 3):
            raise ValueError("umeyama: need at least 3 points with positive weight")
    w = w / np.sum(w, axis=-1, keepdims=True)
    mu_s = np.sum(w[..., None] * src, axis=-2)
    mu_d = np.sum(w[..., None] * dst, axis=-2)
    xs = src - mu_s[..., None, :]
    xd = dst - mu_d[..., None, :]
    var_s = np.sum(w * np.sum(xs * xs, axis=-1), axis=-1)
    scale_ref = np.maximum(1.0, np.sum(mu_s * mu_s, axis=-1))
    degenerate = var_s <= 1e-20 * scale_ref
    if np.any(degenerate):
        raise ValueError(
            f"umeyama: degenerate source in {int(np.count_nonzero(degenerate))} batch element(s): "
            "all points (with positive weight) coincide"
        )
    cov = np.swapaxes(xd * w[..., None], -1, -2) @ xs  # (..., 3, 3) = sum_i w_i xd_i xs_i^T
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d = np.where(d == 0, 1.0, d)
    D = np.ones(S.shape)
    D[..., 2] = d
    R = (U * D[..., None, :]) @ Vt
    if with_scale:
        s = np.sum(S * D, axis=-1) / var_s
    else:
        s = np.ones(var_s.shape)
    t = mu_d - s[..., None] * (R @ mu_s[..., None])[..., 0]
    return s, R, t


def apply_similarity(s: ArrayLike, R: ArrayLike, t: ArrayLike, p: ArrayLike) -> np.ndarray:
    """s R p + t for s (...), R (..., 3, 3), t (..., 3); p is (..., 3) if p.ndim == R.ndim - 1 else (..., N, 3)."""
    s = np.asarray(s, dtype=np.float64)
    R = _as_float(R, "R", last2=(3, 3))
    t = _as_float(t, "t", last=3)
    p = _as_float(p, "p", last=3)
    return _apply_linear(s[..., None, None] * R, t, p)
