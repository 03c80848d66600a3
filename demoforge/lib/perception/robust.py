"""NaN-aware statistics over detections (NaN = no reading): the depth at a hand's anchors, a hand's
translation over its frames."""

from __future__ import annotations

import numpy as np


def nan_median(x: np.ndarray, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Median ignoring NaN along ``axis`` via one sort -> (median (NaN if none valid), count)."""
    x = np.moveaxis(np.asarray(x, dtype=np.float64), axis, -1)
    n = np.sum(~np.isnan(x), axis=-1)
    s = np.sort(x, axis=-1)  # NaN sort to the end
    lo = np.clip((n - 1) // 2, 0, None)
    hi = np.clip(n // 2, 0, None)
    if x.shape[-1] == 0:
        return np.full(x.shape[:-1], np.nan), n
    a = np.take_along_axis(s, lo[..., None], -1)[..., 0]
    b = np.take_along_axis(s, np.minimum(hi, x.shape[-1] - 1)[..., None], -1)[..., 0]
    med = np.where(n > 0, 0.5 * (a + b), np.nan)
    return med, n
