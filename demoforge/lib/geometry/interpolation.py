"""Pose interpolation over time: keyframe splines with slerp or SQUAD, and eased transitions.

Unlike the rest of the package, axis 0 of these functions is time: interpolate_poses samples keyframed
positions and quaternions at query times, cubic_transition eases from one pose to another in n steps.
Conventions: the package docstring of demoforge.lib.geometry.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from demoforge.lib.geometry._checks import _as_float
from demoforge.lib.geometry.rotations import (
    quat_canonical,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_normalize,
    quat_slerp,
)


def hemisphere_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 so consecutive quaternions have non-negative dot product."""
    if q.shape[0] < 2:
        return q
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    flips = np.where(dots < 0.0, -1.0, 1.0)
    signs = np.concatenate([np.ones_like(flips[:1]), np.cumprod(flips, axis=0)], axis=0)
    return q * signs[..., None]


def interpolate_poses(
    times: ArrayLike,
    positions: ArrayLike,
    quats: ArrayLike,
    query_times: ArrayLike,
    rotation: str = "slerp",
    position: str = "cubic",
    spline_bc: str = "not-a-knot",
) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate keyframes (K,) times, (K, ..., 3) positions, (K, ..., 4) quats at (M,) query times -> ((M, ..., 3), (M, ..., 4)).

    Axis 0 is time (extra axes, e.g. two arms, ride along).  Times must be finite and strictly
    increasing; query times outside [times[0], times[-1]] are clamped to the end keyframes.
    Quaternion signs are first made hemisphere-continuous; the output quaternions are unit and
    continuous (not re-canonicalised), equal to the (sign-aligned) keyframe quaternion at keyframe
    times.  position: "cubic" = scipy CubicSpline with bc_type=spline_bc (default "not-a-knot",
    which reproduces polynomials up to degree 3; "natural" also accepted) or "linear".
    rotation: "slerp" (piecewise geodesic) or "squad" (Shoemake's SQUAD with the intermediate
    controls s_i = q_i exp(-(dt_{i-1} log(q_i^-1 q_{i+1}) + dt_i log(q_i^-1 q_{i-1})) / (2 (dt_{i-1} + dt_i))),
    the time-weighted form of the standard -(.. + ..)/4, which makes the angular velocity continuous at
    interior keyframes also for non-uniform spacing; s_0 = q_0, s_{K-1} = q_{K-1}).
    A single keyframe (K = 1) gives a constant output.
    """
    if rotation not in ("slerp", "squad"):
        raise ValueError(f"rotation must be 'slerp' or 'squad', got {rotation!r}")
    if position not in ("cubic", "linear"):
        raise ValueError(f"position must be 'cubic' or 'linear', got {position!r}")
    times = np.asarray(times, dtype=np.float64)
    pos = _as_float(positions, "positions", last=3)
    q = quat_normalize(quats)
    qt = np.asarray(query_times, dtype=np.float64)
    if times.ndim != 1 or times.size < 1:
        raise ValueError(f"times must be a non-empty 1-D array, got shape {times.shape}")
    K = times.size
    if pos.ndim < 2 or pos.shape[0] != K or q.ndim < 2 or q.shape[0] != K:
        raise ValueError(
            f"positions {pos.shape} and quats {q.shape} must have {K} keyframes along axis 0"
        )
    if qt.ndim != 1:
        raise ValueError(f"query_times must be 1-D, got shape {qt.shape}")
    if not (np.isfinite(times).all() and np.isfinite(pos).all() and np.isfinite(qt).all()):
        raise ValueError("times, positions and query_times must be finite")
    if np.any(np.diff(times) <= 0):
        raise ValueError("times must be strictly increasing")
    q = hemisphere_continuous(q)
    M = qt.size
    if K == 1:
        return (np.broadcast_to(pos, (M,) + pos.shape[1:]).copy(), np.broadcast_to(q, (M,) + q.shape[1:]).copy())
    tq = np.clip(qt, times[0], times[-1])

    # positions
    if position == "cubic":
        out_p = CubicSpline(times, pos, axis=0, bc_type=spline_bc)(tq)
    else:
        flat = pos.reshape(K, -1)
        i = np.clip(np.searchsorted(times, tq, side="right") - 1, 0, K - 2)
        h = ((tq - times[i]) / (times[i + 1] - times[i]))[:, None]
        out_p = ((1.0 - h) * flat[i] + h * flat[i + 1]).reshape((M,) + pos.shape[1:])

    # rotations: segment index and local parameter
    i = np.clip(np.searchsorted(times, tq, side="right") - 1, 0, K - 2)
    h = (tq - times[i]) / (times[i + 1] - times[i])
    h_b = h.reshape((M,) + (1,) * (q.ndim - 2))
    qa, qb = q[i], q[i + 1]
    if rotation == "slerp":
        out_q = quat_slerp(qa, qb, h_b)
    else:
        ctrl = q.copy()
        if K > 2:
            qi = q[1:-1]
            inv = quat_conjugate(qi)
            log_next = quat_log(quat_canonical(quat_multiply(inv, q[2:])))
            log_prev = quat_log(quat_canonical(quat_multiply(inv, q[:-2])))
            dt = np.diff(times)
            dt_prev = dt[:-1].reshape((K - 2,) + (1,) * (q.ndim - 1))
            dt_next = dt[1:].reshape((K - 2,) + (1,) * (q.ndim - 1))
            tangent = -(dt_prev * log_next + dt_next * log_prev) / (2.0 * (dt_prev + dt_next))
            ctrl[1:-1] = quat_multiply(qi, quat_exp(tangent))
        # keep controls on the same hemisphere as their keyframe
        ctrl = np.where(np.sum(ctrl * q, axis=-1, keepdims=True) < 0, -ctrl, ctrl)
        outer = quat_slerp(qa, qb, h_b)
        # Shoemake's SQUAD uses the sign-preserving slerp for the inner and blending steps; a
        # shortest-path blend would jump where outer and inner are ~90 degrees (dot ~ 0) apart.
        inner = quat_slerp(ctrl[i], ctrl[i + 1], h_b, shortest=False)
        out_q = quat_slerp(outer, inner, 2.0 * h_b * (1.0 - h_b), shortest=False)
    out_q = out_q / np.linalg.norm(out_q, axis=-1, keepdims=True)
    return out_p, out_q


def cubic_transition(
    p0: ArrayLike, q0: ArrayLike, p1: ArrayLike, q1: ArrayLike, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """n >= 2 poses from (p0 (..., 3), q0 (..., 4)) to (p1, q1), time-first: ((n, ..., 3), (n, ..., 4)).

    Eased parameter e(u) = 3u^2 - 2u^3 (cubic Hermite with zero end velocities, u = linspace(0, 1, n));
    position (1 - e) p0 + e p1, rotation slerp(q0, q1, e) along the shortest path.  The first pose is
    exactly (p0, normalised q0); the last is exactly p1 and +-normalised q1 (the sign that keeps the
    quaternion path continuous from q0).
    """
    if int(n) != n or n < 2:
        raise ValueError(f"cubic_transition: n must be an integer >= 2, got {n!r}")
    n = int(n)
    p0 = _as_float(p0, "p0", last=3)
    p1 = _as_float(p1, "p1", last=3)
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    if not (np.isfinite(p0).all() and np.isfinite(p1).all()):
        raise ValueError("cubic_transition: positions must be finite")
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)
    u = np.linspace(0.0, 1.0, n)
    e = u * u * (3.0 - 2.0 * u)
    pb = np.broadcast_shapes(p0.shape, p1.shape)
    qb = np.broadcast_shapes(q0.shape, q1.shape)
    e_p = e.reshape((n,) + (1,) * len(pb))
    e_q = e.reshape((n,) + (1,) * (len(qb) - 1))
    pos = (1.0 - e_p) * p0 + e_p * p1
    quat = quat_slerp(q0, q1, e_q)
    quat[0] = np.broadcast_to(q0, qb)
    quat[-1] = np.broadcast_to(q1, qb)
    return pos, quat
