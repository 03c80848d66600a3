"""Repair of the two hands' tracks over time: left/right swap repair, the outlier freeze, gap filling.

Steps 1, 4 and 5 of the depth-alignment pipeline (:func:`demoforge.lib.ingest.alignment.align_to_depth`,
whose module docstring states the rules and re-exports these names): :func:`repair_swaps` decides per
frame whether the two detector slots are swapped, from 2D centroids; :func:`freeze_outliers` rejects
frames that jump too far from the last accepted keypoints (the thesis's MSE rule, capped); and
:func:`fill_gaps` fills undetected or rejected frames from the accepted ones (interpolate or hold).
"""

from __future__ import annotations

import numpy as np


# --------------------------------------------------------------------------- swap repair


def repair_swaps(centroids_px: np.ndarray, present: np.ndarray, margin_px: float = 10.0,
                 majority: bool = True, max_age: int | None = None) -> np.ndarray:
    """Decide per frame whether the two slots are swapped. Returns swapped (T,) bool.

    centroids_px: (T, 2, 2) 2D centroid of each slot's hand (NaN if absent); present (T, 2).
    Sequential assignment against the last repaired position of each physical hand (see the
    module docstring); ``majority`` keeps the take-level labelling closest to the detector's.
    ``max_age``: a hand's last position older than this many frames is forgotten (with sparse
    detections a stale position says nothing about where the hand is now); None = never.
    """
    c = np.asarray(centroids_px, dtype=np.float64)
    p = np.asarray(present, dtype=bool) & np.isfinite(c).all(-1)
    T = c.shape[0]
    swapped = np.zeros(T, dtype=bool)
    cl = c.tolist()
    pl = p.tolist()
    ref = [None, None]  # last repaired (x, y) of physical left / right
    ref_t = [0, 0]
    for t in range(T):
        p0, p1 = pl[t]
        if not (p0 or p1):
            continue
        if max_age is not None:
            ref = [r if r is None or t - rt <= max_age else None for r, rt in zip(ref, ref_t)]
        a, b = cl[t]
        sw = False
        r0, r1 = ref
        if p0 and p1:
            if r0 is not None and r1 is not None:
                idc = _d(a, r0) + _d(b, r1)
                crs = _d(a, r1) + _d(b, r0)
                sw = crs + margin_px < idc
            elif r0 is not None:  # only left seen so far: the slot closer to it is the left hand
                sw = _d(b, r0) + margin_px < _d(a, r0)
            elif r1 is not None:
                sw = _d(a, r1) + margin_px < _d(b, r1)
        else:
            x = a if p0 else b
            own, other = (r0, r1) if p0 else (r1, r0)
            if own is not None and other is not None:
                sw = _d(x, other) + margin_px < _d(x, own)
            elif own is None and other is not None:
                # never seen this hand; the other hand is known: far from it -> this label is right
                sw = _d(x, other) < margin_px
        swapped[t] = sw
        if sw:
            if p0:
                ref[1], ref_t[1] = a, t
            if p1:
                ref[0], ref_t[0] = b, t
        else:
            if p0:
                ref[0], ref_t[0] = a, t
            if p1:
                ref[1], ref_t[1] = b, t
    if majority:
        any_p = p.any(axis=1)
        if np.count_nonzero(swapped & any_p) * 2 > np.count_nonzero(any_p):
            swapped = ~swapped & any_p
    return swapped


def _d(a, b) -> float:
    return ((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2) ** 0.5


# --------------------------------------------------------------------------- freeze / fill


def freeze_outliers(joints: np.ndarray, present: np.ndarray, threshold: float,
                    max_freeze: int = 15) -> np.ndarray:
    """Thesis outlier rule per hand -> frozen (T, 2) bool (frames whose detection is rejected).

    joints (T, 2, J, 3); present (T, 2). A present frame whose MSE (mean over joints of the squared
    distance) to the last accepted frame exceeds ``threshold`` is rejected; rejection continues
    until a frame comes back under the threshold or ``max_freeze`` consecutive frames were rejected
    (then the frame is accepted). The first present frame is always accepted. Only frames where the
    MSE to the previous present raw frame is above the threshold can start a freeze, so the scalar
    loop runs over those frames' runs only.
    """
    x = np.asarray(joints, dtype=np.float64)
    present = np.asarray(present, dtype=bool)
    T = x.shape[0]
    frozen = np.zeros((T, 2), dtype=bool)
    if not np.isfinite(threshold):
        return frozen
    for h in range(2):
        idx = np.flatnonzero(present[:, h])
        if idx.size < 2:
            continue
        xs = x[idx, h]
        mse_prev = np.mean(np.sum((xs[1:] - xs[:-1]) ** 2, -1), -1)
        cand = np.flatnonzero(mse_prev > threshold) + 1  # positions in idx that jump
        if cand.size == 0:
            continue
        k = int(cand[0])
        n = idx.size
        last_ok = k - 1
        run = 0
        rej = np.zeros(n, dtype=bool)
        cand_set = cand.tolist()
        ci = 0
        while k < n:
            mse = float(np.mean(np.sum((xs[k] - xs[last_ok]) ** 2, -1)))
            if mse > threshold and run < max_freeze:
                rej[k] = True
                run += 1
                k += 1
                continue
            # accepted: if it came straight after an accepted frame, skip ahead to the next jump
            last_ok, run = k, 0
            while ci < len(cand_set) and cand_set[ci] <= k:
                ci += 1
            if ci >= len(cand_set):
                break
            nxt = cand_set[ci]
            last_ok = nxt - 1
            k = nxt
        frozen[idx[rej], h] = True
    return frozen


def fill_gaps(joints: np.ndarray, good: np.ndarray, mode: str = "interpolate") -> np.ndarray:
    """Fill frames where ``good`` (T, 2) is False from the good frames of the same hand.

    "interpolate": linear in time between the previous and next good frame (held at the ends);
    "hold": the previous good frame (the first good frame before the first one). A hand with no
    good frame stays NaN. joints (T, 2, ...) -> same shape, finite wherever the hand has a good frame.
    """
    x = np.asarray(joints, dtype=np.float64)
    good = np.asarray(good, dtype=bool)
    T = x.shape[0]
    t = np.arange(T)
    prev = np.maximum.accumulate(np.where(good, t[:, None], -1), axis=0)          # (T, 2)
    nxt = np.minimum.accumulate(np.where(good, t[:, None], T)[::-1], axis=0)[::-1]  # (T, 2)
    has_prev, has_next = prev >= 0, nxt < T
    p = np.where(has_prev, prev, np.where(has_next, nxt, 0))
    n = np.where(has_next, nxt, p)
    if mode == "hold":
        n = p
    elif mode != "interpolate":
        raise ValueError(f"fill mode must be 'interpolate' or 'hold', got {mode!r}")
    span = np.maximum(n - p, 1)
    w = np.where(n > p, (t[:, None] - p) / span, 0.0)
    hands = np.arange(2)[None, :]
    extra = (1,) * (x.ndim - 2)
    xp, xn = x[p, hands], x[n, hands]
    w = w.reshape(w.shape + extra)
    out = np.where(w == 0, xp, (1 - w) * xp + w * xn)
    out = np.where(good.reshape(good.shape + extra), x, out)
    none = ~(has_prev | has_next)
    out[none] = np.nan
    return out
