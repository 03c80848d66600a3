"""Input checks shared by the geometry modules: float conversion with shape checks and unit vectors.

Private to demoforge.lib.geometry (the package docstring states the conventions); every public function
passes its array arguments through these so a wrong shape or a zero-length vector raises ValueError.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

_EPS_NORM = 1e-12  # below this a quaternion / direction vector is treated as zero-length


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
