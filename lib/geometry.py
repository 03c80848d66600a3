"""Rigid-body geometry for demoforge: quaternions, SE(3), mirroring, alignment, interpolation.

Conventions (docs/architecture.md, fixed):

* quaternions are scalar-last ``[qx, qy, qz, qw]`` (``scipy.spatial.transform.Rotation.as_quat``);
  MuJoCo's scalar-first order appears only through :func:`xyzw_to_wxyz` / :func:`wxyz_to_xyzw`;
* rotations act on column vectors, ``quat_to_matrix(a * b) == quat_to_matrix(a) @ quat_to_matrix(b)``;
* transforms are 4x4 homogeneous matrices ``[[R, t], [0, 1]]``;
* a gripper pose is 8 values ``[x, y, z, qx, qy, qz, qw, g]`` with g = 1 open, 0 closed;
* the gripper frame is z = approach, x = thumb -> index (closing direction), y = z cross x;
* the mirror plane defaults to the world YZ plane (n = (1, 0, 0), d = 0);
* metres, radians, seconds.

Every function is vectorised over leading batch dimensions ``...`` (numpy broadcasting rules)
except where its docstring says the first axis is time (the interpolation functions).
Invalid input (wrong shapes, zero-norm quaternions or vectors, too few points) raises ValueError.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

__all__ = [
    "quat_normalize",
    "quat_canonical",
    "quat_multiply",
    "quat_conjugate",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_angle",
    "quat_exp",
    "quat_log",
    "quat_slerp",
    "xyzw_to_wxyz",
    "wxyz_to_xyzw",
    "skew",
    "rotation_between_vectors",
    "make_transform",
    "transform_inverse",
    "transform_compose",
    "transform_points",
    "pose8_to_transform",
    "transform_to_pose8",
    "pose7_to_transform",
    "transform_to_pose7",
    "reflection_matrix",
    "reflect_points",
    "reflect_rotation",
    "reflect_quat",
    "reflect_transform",
    "reflect_pose8",
    "umeyama",
    "apply_similarity",
    "interpolate_poses",
    "cubic_transition",
    "random_rotations",
    "random_quaternions",
    "yaw_rotation",
]

_EPS_NORM = 1e-12  # below this a quaternion / direction vector is treated as zero-length
_X_AXIS = (1.0, 0.0, 0.0)


# --------------------------------------------------------------------------- helpers


def _as_float(x: ArrayLike, name: str, last: int | None = None, last2: tuple[int, int] | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if last is not None and (a.ndim < 1 or a.shape[-1] != last):
        raise ValueError(f"{name} must have shape (..., {last}), got {a.shape}")
    if last2 is not None and (a.ndim < 2 or a.shape[-2:] != last2):
        raise ValueError(f"{name} must have shape (..., {last2[0]}, {last2[1]}), got {a.shape}")
    return a


def _unit_vectors(v: np.ndarray, name: str) -> np.ndarray:
    """Normalise (..., 3) vectors; ValueError on zero-length or non-finite rows."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    bad = ~np.isfinite(v).all(axis=-1) | ~(norm[..., 0] > _EPS_NORM)
    if np.any(bad):
        raise ValueError(
            f"{name}: {int(np.count_nonzero(bad))} of {bad.size} vector(s) have zero length or non-finite values"
        )
    return v / norm


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


# --------------------------------------------------------------------------- SE(3)


def make_transform(R: ArrayLike, t: ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotation and (..., 3) translation (broadcast) -> (..., 4, 4) homogeneous transform."""
    R = _as_float(R, "R", last2=(3, 3))
    t = _as_float(t, "t", last=3)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def transform_inverse(T: ArrayLike) -> np.ndarray:
    """(..., 4, 4) rigid transform -> its inverse in closed form [[R^T, -R^T t], [0, 1]]."""
    T = _as_float(T, "T", last2=(4, 4))
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def transform_compose(A: ArrayLike, B: ArrayLike) -> np.ndarray:
    """(..., 4, 4) A @ B (broadcast): apply B first, then A."""
    A = _as_float(A, "A", last2=(4, 4))
    B = _as_float(B, "B", last2=(4, 4))
    return A @ B


def _apply_linear(M: np.ndarray, t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """p -> M p + t; p is (..., 3) one point per batch element if p.ndim == M.ndim - 1, else (..., N, 3)."""
    if p.ndim == M.ndim - 1:
        return (M @ p[..., None])[..., 0] + t
    return p @ np.swapaxes(M, -1, -2) + t[..., None, :]


def transform_points(T: ArrayLike, p: ArrayLike) -> np.ndarray:
    """Apply (..., 4, 4) T to points p: (..., 3) one per transform if p.ndim == T.ndim - 1, else (..., N, 3) sets."""
    T = _as_float(T, "T", last2=(4, 4))
    p = _as_float(p, "p", last=3)
    return _apply_linear(T[..., :3, :3], T[..., :3, 3], p)


def pose8_to_transform(p8: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(..., 8) [x y z qx qy qz qw g] -> ((..., 4, 4) transform (quaternion normalised), (...) gripper g)."""
    p8 = _as_float(p8, "p8", last=8)
    return make_transform(quat_to_matrix(p8[..., 3:7]), p8[..., :3]), p8[..., 7].copy()


def transform_to_pose8(T: ArrayLike, g: ArrayLike = 1.0) -> np.ndarray:
    """(..., 4, 4) transform and gripper g (..., broadcast; default 1 = open) -> (..., 8) pose, qw >= 0."""
    T = _as_float(T, "T", last2=(4, 4))
    p7 = transform_to_pose7(T)
    g = np.broadcast_to(np.asarray(g, dtype=np.float64), T.shape[:-2])
    return np.concatenate([p7, g[..., None]], axis=-1)


def pose7_to_transform(p7: ArrayLike) -> np.ndarray:
    """(..., 7) [x y z qx qy qz qw] -> (..., 4, 4) transform (quaternion normalised)."""
    p7 = _as_float(p7, "p7", last=7)
    return make_transform(quat_to_matrix(p7[..., 3:7]), p7[..., :3])


def transform_to_pose7(T: ArrayLike) -> np.ndarray:
    """(..., 4, 4) transform -> (..., 7) [x y z qx qy qz qw], canonical qw >= 0."""
    T = _as_float(T, "T", last2=(4, 4))
    return np.concatenate([T[..., :3, 3], matrix_to_quat(T[..., :3, :3])], axis=-1)


# --------------------------------------------------------------------------- mirroring


def reflection_matrix(n: ArrayLike = _X_AXIS) -> np.ndarray:
    """(..., 3) plane normal (normalised here) -> (..., 3, 3) Householder reflection I - 2 n n^T (det -1)."""
    n = _unit_vectors(_as_float(n, "n", last=3), "reflection_matrix(n)")
    return np.eye(3) - 2.0 * n[..., :, None] * n[..., None, :]


def reflect_points(p: ArrayLike, n: ArrayLike = _X_AXIS, d: ArrayLike = 0.0) -> np.ndarray:
    """Mirror (..., 3) points across the plane n.x = d (n normalised here): p - 2 (n.p - d) n."""
    p = _as_float(p, "p", last=3)
    n = _unit_vectors(_as_float(n, "n", last=3), "reflect_points(n)")
    dist = np.sum(p * n, axis=-1, keepdims=True) - np.asarray(d, dtype=np.float64)[..., None]
    return p - 2.0 * dist * n


def _check_flip_column(flip_column: int) -> int:
    if flip_column not in (0, 1, 2):
        raise ValueError(f"flip_column must be 0, 1 or 2, got {flip_column!r}")
    return int(flip_column)


def reflect_rotation(R: ArrayLike, n: ArrayLike = _X_AXIS, flip_column: int = 1) -> np.ndarray:
    """Mirror (..., 3, 3) frames: (I - 2 n n^T) R, then negate column flip_column so det = +1 (thesis eq. 2-3).

    The default flip_column=1 negates the gripper y axis: the mirrored frame keeps the reflected
    approach z and the reflected closing direction x, and y = z cross x again.
    """
    R = _as_float(R, "R", last2=(3, 3))
    k = _check_flip_column(flip_column)
    out = reflection_matrix(n) @ R
    sign = np.ones(3)
    sign[k] = -1.0
    return out * sign


def reflect_quat(q: ArrayLike, n: ArrayLike = _X_AXIS, flip_column: int = 1) -> np.ndarray:
    """Quaternion form of reflect_rotation for (..., 4): [n, 0] * q * [e_k, 0]; applying it twice returns q exactly."""
    q = quat_normalize(q)
    k = _check_flip_column(flip_column)
    n = _unit_vectors(_as_float(n, "n", last=3), "reflect_quat(n)")
    qn = np.concatenate([n, np.zeros_like(n[..., :1])], axis=-1)
    qe = np.zeros(4)
    qe[k] = 1.0
    # (I - 2nn^T) = -Rot(pi, n) and diag with -1 at k = -Rot(pi, e_k): the two signs cancel.
    return quat_multiply(quat_multiply(qn, q), qe)


def reflect_transform(T: ArrayLike, n: ArrayLike = _X_AXIS, d: ArrayLike = 0.0, flip_column: int = 1) -> np.ndarray:
    """Mirror (..., 4, 4) poses across n.x = d: rotation by reflect_rotation, translation by reflect_points."""
    T = _as_float(T, "T", last2=(4, 4))
    return make_transform(reflect_rotation(T[..., :3, :3], n, flip_column), reflect_points(T[..., :3, 3], n, d))


def reflect_pose8(p8: ArrayLike, n: ArrayLike = _X_AXIS, d: ArrayLike = 0.0, flip_column: int = 1) -> np.ndarray:
    """Mirror (..., 8) gripper poses across n.x = d (quaternion via reflect_quat, not re-canonicalised); g kept."""
    p8 = _as_float(p8, "p8", last=8)
    pos = reflect_points(p8[..., :3], n, d)
    q = reflect_quat(p8[..., 3:7], n, flip_column)
    batch = np.broadcast_shapes(pos.shape[:-1], q.shape[:-1], p8.shape[:-1])
    g = np.broadcast_to(p8[..., 7:8], batch + (1,))
    return np.concatenate([np.broadcast_to(pos, batch + (3,)), np.broadcast_to(q, batch + (4,)), g], axis=-1)


# --------------------------------------------------------------------------- alignment


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


# --------------------------------------------------------------------------- interpolation


def _hemisphere_continuous(q: np.ndarray) -> np.ndarray:
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
    q = _hemisphere_continuous(q)
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
