"""Rotations: scalar-last quaternions, rotation matrices, vectors, random and yaw rotations.

Quaternion algebra (normalise, multiply, exp/log, slerp), conversion to and from 3x3 matrices, the
MuJoCo scalar-first boundary, cross-product matrices, the minimal rotation between two vectors, and
uniformly sampled rotations.  Conventions: the package docstring of demoforge.lib.geometry.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from demoforge.lib.geometry._checks import _EPS_NORM, _as_float, _unit_vectors


# --------------------------------------------------------------------------- quaternions


def quat_normalize(q: ArrayLike) -> np.ndarray:
    """(..., 4) -> (..., 4) unit quaternions (scalar-last); ValueError on zero-norm or non-finite rows."""
    q = _as_float(q, "q", last=4)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~np.isfinite(q).all(axis=-1) | ~(norm[..., 0] > _EPS_NORM)
    if np.any(bad):
        raise ValueError(
            f"quat_normalize: {int(np.count_nonzero(bad))} of {bad.size} quaternion(s) "
            "have zero norm or non-finite values"
        )
    return q / norm


def quat_canonical(q: ArrayLike) -> np.ndarray:
    """(..., 4) -> (..., 4) same rotation with qw >= 0 (sign flip only, no normalisation)."""
    q = _as_float(q, "q", last=4)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quat_multiply(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Hamilton product a*b of (..., 4) scalar-last quaternions (broadcast); matrix(a*b) = matrix(a) @ matrix(b)."""
    a = _as_float(a, "a", last=4)
    b = _as_float(b, "b", last=4)
    x1, y1, z1, w1 = np.moveaxis(a, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ],
        axis=-1,
    )


def quat_conjugate(q: ArrayLike) -> np.ndarray:
    """(..., 4) -> (..., 4) conjugate [-qx, -qy, -qz, qw] (the inverse for unit quaternions)."""
    q = _as_float(q, "q", last=4)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_to_matrix(q: ArrayLike) -> np.ndarray:
    """(..., 4) scalar-last quaternions (normalised first) -> (..., 3, 3) rotation matrices."""
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(R: ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit scalar-last quaternions, canonical qw >= 0 (Shepperd)."""
    R = _as_float(R, "R", last2=(3, 3))
    if not np.isfinite(R).all():
        raise ValueError("matrix_to_quat: non-finite rotation matrix entries")
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = r00 + r11 + r22
    # Four candidate (unnormalised) quaternions, each accurate when its pivot is largest.
    c_x = np.stack([1 + r00 - r11 - r22, R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0],
                    R[..., 2, 1] - R[..., 1, 2]], axis=-1)
    c_y = np.stack([R[..., 0, 1] + R[..., 1, 0], 1 - r00 + r11 - r22, R[..., 1, 2] + R[..., 2, 1],
                    R[..., 0, 2] - R[..., 2, 0]], axis=-1)
    c_z = np.stack([R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1], 1 - r00 - r11 + r22,
                    R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    c_w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1],
                    1 + tr], axis=-1)
    cands = np.stack([c_x, c_y, c_z, c_w], axis=-2)  # (..., 4, 4)
    pivot = np.argmax(np.stack([r00, r11, r22, tr], axis=-1), axis=-1)
    q = np.take_along_axis(cands, pivot[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_canonical(q)


def quat_angle(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Geodesic angle in [0, pi] (radians) between (..., 4) rotations a and b; invariant to either sign."""
    r = quat_multiply(quat_conjugate(quat_normalize(a)), quat_normalize(b))
    return 2.0 * np.arctan2(np.linalg.norm(r[..., :3], axis=-1), np.abs(r[..., 3]))


def quat_exp(v: ArrayLike) -> np.ndarray:
    """(..., 3) pure-quaternion vector part -> (..., 4) unit quaternion [sin|v| v/|v|, cos|v|] (half-angle |v|)."""
    v = _as_float(v, "v", last=3)
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.concatenate([np.sinc(theta / np.pi) * v, np.cos(theta)], axis=-1)


def quat_log(q: ArrayLike) -> np.ndarray:
    """(..., 4) quaternion (normalised) -> (..., 3) vector part of its log (half rotation vector, |.| <= pi); inverse of quat_exp."""
    q = quat_normalize(q)
    u, w = q[..., :3], q[..., 3:4]
    s = np.linalg.norm(u, axis=-1, keepdims=True)
    theta = np.arctan2(s, w)  # accurate for all s > 0; s == 0 means u == 0 and gives 0
    return (theta / np.where(s > 0, s, 1.0)) * u


def quat_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike, shortest: bool = True) -> np.ndarray:
    """Slerp q0 (q0^-1 q1)^t of (..., 4) quaternions at t (...) (broadcast); shortest=False keeps q1's sign as given."""
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    t = np.asarray(t, dtype=np.float64)
    rel = quat_multiply(quat_conjugate(q0), q1)
    if shortest:
        rel = quat_canonical(rel)
    return quat_multiply(q0, quat_exp(t[..., None] * quat_log(rel)))


def xyzw_to_wxyz(q: ArrayLike) -> np.ndarray:
    """(..., 4) scalar-last [x, y, z, w] -> scalar-first [w, x, y, z] (MuJoCo boundary only)."""
    q = _as_float(q, "q", last=4)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def wxyz_to_xyzw(q: ArrayLike) -> np.ndarray:
    """(..., 4) scalar-first [w, x, y, z] (MuJoCo) -> scalar-last [x, y, z, w]."""
    q = _as_float(q, "q", last=4)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


# --------------------------------------------------------------------------- vectors


def skew(v: ArrayLike) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrix [v]x with [v]x @ w = v x w."""
    v = _as_float(v, "v", last=3)
    x, y, z = np.moveaxis(v, -1, 0)
    o = np.zeros_like(x)
    return np.stack(
        [np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], axis=-2
    )


def rotation_between_vectors(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Minimal rotation (..., 3, 3) with R @ a_hat = b_hat for (..., 3) vectors a, b (broadcast).

    Equals the Rodrigues form I + [v]x + [v]x^2 (1 - a.b)/|v|^2 (v = a x b), but is evaluated through
    the half-way vector h = (a+b)/|a+b| as the quaternion [a x h, |a+b|/2] (= [a x h, a.h]), which stays accurate to
    machine precision up to the antiparallel limit.  Parallel inputs give exactly I; exactly
    antiparallel inputs (|a+b| < 1e-12) give the rotation by pi about the unit axis
    normalize(a x e_k), e_k the world axis in which |a| is smallest (deterministic).
    ValueError for zero-length or non-finite inputs.
    """
    a = _unit_vectors(_as_float(a, "a", last=3), "rotation_between_vectors(a)")
    b = _unit_vectors(_as_float(b, "b", last=3), "rotation_between_vectors(b)")
    a, b = np.broadcast_arrays(a, b)
    s = a + b
    s_norm = np.linalg.norm(s, axis=-1, keepdims=True)
    anti = s_norm[..., 0] < 1e-12
    h = s / np.where(anti[..., None], 1.0, s_norm)
    # a.h = |a+b|/2 for unit a, b; using |s|/2 rather than the dot product keeps R @ a = b accurate
    # when a and b are nearly antiparallel (there a.h suffers from the rounding of |a| and |b|).
    q = np.concatenate([np.cross(a, h), 0.5 * s_norm], axis=-1)
    # Antiparallel: rotation by pi about an axis perpendicular to a -> quaternion [u, 0].
    k = np.argmin(np.abs(a), axis=-1)
    e = np.eye(3)[k]
    u = np.cross(a, e)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    q_anti = np.concatenate([u, np.zeros_like(u[..., :1])], axis=-1)
    q = np.where(anti[..., None], q_anti, q)
    return quat_to_matrix(q)


# --------------------------------------------------------------------------- sampling


def random_quaternions(n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """(n, 4) uniformly distributed unit quaternions (Haar measure), canonical qw >= 0."""
    rng = np.random.default_rng(rng)
    q = rng.standard_normal((int(n), 4))
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    # A norm below 1e-12 has probability ~0; redraw such rows deterministically from the same rng.
    while np.any(norm < 1e-12):  # pragma: no cover - practically unreachable
        bad = norm[:, 0] < 1e-12
        q[bad] = rng.standard_normal((int(bad.sum()), 4))
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_canonical(q / norm)


def random_rotations(n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """(n, 3, 3) uniformly distributed rotation matrices (Haar measure on SO(3))."""
    return quat_to_matrix(random_quaternions(n, rng))


def yaw_rotation(theta: ArrayLike) -> np.ndarray:
    """(...) angles in radians -> (..., 3, 3) rotations about the world z axis (counter-clockwise seen from +z)."""
    theta = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    o, i = np.zeros_like(theta), np.ones_like(theta)
    return np.stack(
        [np.stack([c, -s, o], -1), np.stack([s, c, o], -1), np.stack([o, o, i], -1)], axis=-2
    )
