"""The continuous 6D rotation representation (Zhou et al., CVPR 2019): the first two columns of the
rotation matrix.  Quaternions jump (q and -q are the same rotation) and have a unit-norm
constraint; a network regresses 6 free numbers instead and Gram-Schmidt turns them back into a
rotation.  numpy for data preparation, torch for the loss; quaternions are scalar-last [x, y, z, w]
(docs/architecture.md, Conventions)."""

from __future__ import annotations

import numpy as np

from demoforge.lib.geometry import matrix_to_quat, quat_to_matrix

_EPS = 1e-8


def quat_to_6d(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions [x, y, z, w] -> (..., 6): columns 0 and 1 of the rotation matrix."""
    R = quat_to_matrix(np.asarray(q, dtype=np.float64))
    return np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


def matrix_from_6d(d6: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 3, 3) rotation matrices by Gram-Schmidt (any non-degenerate input is valid)."""
    d6 = np.asarray(d6, dtype=np.float64)
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / np.maximum(np.linalg.norm(a1, axis=-1, keepdims=True), _EPS)
    a2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = a2 / np.maximum(np.linalg.norm(a2, axis=-1, keepdims=True), _EPS)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-1)


def quat_from_6d(d6: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 4) unit quaternions [x, y, z, w] (sign: the geometry module's canonical choice)."""
    return matrix_to_quat(matrix_from_6d(d6))


def torch_matrix_from_6d(d6):
    """torch (..., 6) -> (..., 3, 3), differentiable Gram-Schmidt (for a geodesic loss)."""
    import torch

    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = torch.nn.functional.normalize(a1, dim=-1, eps=_EPS)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1, eps=_EPS)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def torch_geodesic(d6_pred, d6_true):
    """Angle (rad) between the rotations of two torch (..., 6) batches; gradients stay finite at 0."""
    import torch

    Ra, Rb = torch_matrix_from_6d(d6_pred), torch_matrix_from_6d(d6_true)
    tr = (Ra * Rb).sum(dim=(-2, -1))  # trace(Ra^T Rb)
    return torch.acos(torch.clamp((tr - 1.0) / 2.0, -1.0 + 1e-6, 1.0 - 1e-6))
