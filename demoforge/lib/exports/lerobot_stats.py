"""LeRobot's statistics (meta/stats.json and the episodes' stats/<feature>/<stat>) of a demoforge export.

Statistics are computed as LeRobot computes them for a dataset it records
(lerobot/datasets/compute_stats.py): per episode, min / max / mean / std and quantiles read off a
5,000-bin histogram spanning the episode's range (linear inside the bin), then aggregated over the
episodes: min of mins, max of maxes, count-weighted mean, pooled std, and quantiles as the
count-weighted mean of the episodes' quantiles (not the quantiles of all frames). Images: per
channel over LeRobot's sample of each episode's frames (downsampled past 300 px), scaled to [0, 1].
Used by the writer in :mod:`demoforge.lib.exports.lerobot`, which re-exports these names.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.exports import episode_starts

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{int(round(q * 100)):02d}" for q in QUANTILES)
STAT_KEYS = ("min", "max", "mean", "std", "count") + QUANTILE_KEYS
HISTOGRAM_BINS = 5000  # RunningQuantileStats' num_quantile_bins


def lerobot_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's statistics of each of E episodes: ``x`` (E, L, D) -> {stat: (E, D)}, count (E, 1).

    A vectorised port of compute_stats.RunningQuantileStats fed one episode in one update: a
    5,000-bin histogram over [min - 1e-10, max + 1e-10] per dimension, the quantile q at rank q * L
    linearly inside its bin (the low edge when it falls in the first bin). Equal to LeRobot's up to
    the bin an element on a bin edge is counted in (one bin width, range / 5,000). Episodes of one
    step get their mean as every quantile, as in LeRobot.
    """
    x = np.asarray(x)
    x = x.astype(np.result_type(x.dtype, np.float32), copy=False)  # as LeRobot: float32 stays float32
    E, L, D = x.shape
    mean = x.mean(axis=1)
    out = {"min": x.min(axis=1), "max": x.max(axis=1), "mean": mean,
           "count": np.full((E, 1), L, np.int64)}
    if L < 2:
        out["std"] = np.zeros_like(mean)
        out.update({k: mean.copy() for k in QUANTILE_KEYS})
        return out
    out["std"] = np.sqrt(np.maximum(0, (x * x).mean(axis=1) - mean * mean))
    lo = out["min"].astype(np.float64) - 1e-10
    width = (out["max"].astype(np.float64) + 1e-10 - lo) / HISTOGRAM_BINS
    xs = np.sort(np.moveaxis(x, 1, 2), axis=2)                              # (E, D, L) sorted
    b = np.clip(np.floor((xs - lo[..., None]) / width[..., None]), 0, HISTOGRAM_BINS - 1).astype(np.int64)
    # every (episode, dimension) row's bins are sorted: offset row r by r * BINS and the whole array
    # is sorted, so a bin's first and last position in its row are two searchsorted calls
    row = np.arange(E * D, dtype=np.int64).reshape(E, D) * HISTOGRAM_BINS
    keys = (b + row[..., None]).reshape(-1)
    for q, key in zip(QUANTILES, QUANTILE_KEYS):
        target = q * L
        idx = b[:, :, max(int(np.ceil(target)), 1) - 1]                   # (E, D): bin of the rank
        first = np.searchsorted(keys, (row + idx).reshape(-1), "left").reshape(E, D)
        end = np.searchsorted(keys, (row + idx).reshape(-1), "right").reshape(E, D)
        base = np.arange(E * D, dtype=np.int64).reshape(E, D) * L
        before, inside = first - base, end - first
        val = lo + (idx + (target - before) / inside) * width
        out[key] = np.where(idx == 0, lo, val)
    return out


def aggregate_stats(ep: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """LeRobot's aggregate_feature_stats over the episodes' stats {stat: (E, ...)} -> {stat: (...)}."""
    counts = ep["count"].reshape(-1).astype(np.float64)
    total = counts.sum()
    w = counts.reshape((-1,) + (1,) * (ep["mean"].ndim - 1)) / total
    mean = (ep["mean"] * w).sum(axis=0)
    var = ((ep["std"].astype(np.float64) ** 2 + (ep["mean"] - mean) ** 2) * w).sum(axis=0)
    out = {"min": ep["min"].min(axis=0), "max": ep["max"].max(axis=0), "mean": mean, "std": np.sqrt(var),
           "count": np.array([int(total)])}
    out.update({k: (ep[k] * w).sum(axis=0) for k in QUANTILE_KEYS})
    return out


def sample_indices(length: int) -> np.ndarray:
    """The frames of an episode LeRobot samples for image statistics (compute_stats.sample_indices)."""
    n = length if length < 100 else max(100, min(int(length ** 0.75), 10_000))
    return np.round(np.linspace(0, length - 1, n)).astype(int)


def image_stats(frames: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's statistics of one episode's sampled RGB frames (n, H, W, 3) uint8: per channel,
    scaled to [0, 1], shape (3, 1, 1); count = the number of frames."""
    h, w = frames.shape[1:3]
    if max(w, h) >= 300:  # compute_stats.auto_downsample_height_width
        f = int(w / 150) if w > h else int(h / 150)
        frames = frames[:, ::f, ::f]
    s = lerobot_stats(frames.reshape(1, -1, 3))
    out = {k: (v[0] / 255.0).reshape(3, 1, 1) for k, v in s.items() if k != "count"}
    out["count"] = np.array([len(frames)], np.int64)
    return out

def episode_stats(cols: dict, feats: dict, lengths: np.ndarray, max_elements: int = 4_000_000
                   ) -> dict[str, dict[str, np.ndarray]]:
    """Per-episode statistics of every numeric column, vectorised over batches of episodes of
    one length (usually all of them), ``max_elements`` values at a time."""
    n = len(lengths)
    starts = episode_starts(lengths)
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, values in cols.items():
        if feats[name]["dtype"] == "string":
            continue  # LeRobot computes no statistics of strings
        v = values if values.ndim == 2 else values[:, None]
        d = v.shape[1]
        res = {k: np.empty((n, 1 if k == "count" else d), np.int64 if k == "count" else np.float64)
               for k in STAT_KEYS}
        for L in np.unique(lengths):
            eps = np.flatnonzero(lengths == L)
            step = max(1, max_elements // (int(L) * d))
            for j in range(0, len(eps), step):
                e = eps[j:j + step]
                rows = (starts[e][:, None] + np.arange(L)[None, :]).reshape(-1)
                s = lerobot_stats(v[rows].reshape(len(e), int(L), d))
                for k in STAT_KEYS:
                    res[k][e] = s[k]
        out[name] = res
    return out
