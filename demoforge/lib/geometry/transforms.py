"""Rigid transforms: 4x4 SE(3) matrices, 7- and 8-value poses, and mirroring across a plane.

Building, inverting, composing and applying homogeneous transforms; converting them to and from
the [x y z qx qy qz qw (g)] pose rows; and reflecting points, frames, quaternions and gripper poses
across a plane with the handedness kept (det +1).  Conventions: the package docstring of demoforge.lib.geometry.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from demoforge.lib.geometry._checks import _as_float, _unit_vectors
from demoforge.lib.geometry.rotations import matrix_to_quat, quat_multiply, quat_normalize, quat_to_matrix

_X_AXIS = (1.0, 0.0, 0.0)


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
