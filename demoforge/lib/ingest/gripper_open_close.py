"""Open/close state of the two-finger gripper from the fingertip distance d(t) (thesis section 5.2).

Open/close (:func:`gripper_state`), g = 1 open, 0 closed:

* ``"threshold"`` -- the thesis: closed iff d_fingertips < w_gripper (one fixed value);
* ``"manual"`` -- annotated [start, end) frame ranges per hand override everything (the thesis's
  final choice, 5.2);
* ``"auto"`` (the default automatic method, "grasp basins") -- per hand and take, on the
  fingertip distance d(t) median-filtered over ``smooth_frames``:

  1. A grasp is approached with the hand open wider than it will hold the object (pre-grasp)
     and left by opening again (release); at rest before and after, the hand has its relaxed
     aperture, which may be *smaller* than the grasp width of a large object (thesis 5.2: one
     threshold cannot separate them). So the grasp is a *basin* of d: the rim level is
     ``level(t) = min(max_{s<=t} d(s), max_{s>=t} d(s))`` ("water filling" of d), and the basin
     depth is ``level(t) - d(t)``. Rest phases at the start and end of the take are not basins
     (nothing wider before / after them).
  2. Connected runs with depth > ``basin_eps`` form basins (the rims are taken from d
     median-filtered over ``rim_smooth_frames``, so a noise spike makes no rim); a basin counts as
     a grasp when it lasts ``min_grasp_frames`` and its floor (the 10th percentile of d in it)
     lies at least ``min_depth_m`` below its level. The grasp width is where the fingers stop:
     the floor. Inside a grasp basin the hand is closed where d is in the lower part of
     the basin: hysteresis between floor + ``frac_close`` x (level - floor) (enter closed) and
     floor + ``frac_open`` x (level - floor) (leave closed).
  3. States shorter than ``min_state_frames`` are merged into the preceding state.
  4. Fallback: a hand with no grasp basin is classified by a two-cluster (Otsu) split of d with
     the same hysteresis, provided the clusters are separated by at least ``min_depth_m``
     (bimodal); else it is open throughout.

  ``"otsu"`` -- the two-cluster split alone (per hand and take), with hysteresis and minimum
  state duration; kept for comparison.

Part of the hand-to-gripper mapping (:mod:`demoforge.lib.ingest.gripper_mapping`, which re-exports
these names); the pose itself is mapped there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
from scipy.ndimage import median_filter


@dataclass(frozen=True)
class GripperStateConfig:
    """Parameters of the open/close methods (see the module docstring)."""

    #: Thesis fixed threshold w_gripper (m): closed iff fingertip distance < it.
    w_gripper: float = 0.06
    #: Median filter length (frames) applied to d before the automatic methods.
    smooth_frames: int = 7
    #: Minimum basin depth / cluster separation (m) for a grasp to be detected.
    min_depth_m: float = 0.02
    #: Runs with depth below this (m) are not basins (noise).
    basin_eps: float = 0.004
    #: Longer median filter (frames) of d for the basin rims (a pre-grasp opening lasts longer
    #: than this; single-frame spikes must not make a rim).
    rim_smooth_frames: int = 15
    #: A grasp basin shorter than this (frames) is ignored.
    min_grasp_frames: int = 15
    #: Hysteresis: enter closed below floor + frac_close (level - floor), leave above frac_open.
    frac_close: float = 0.25
    frac_open: float = 0.4
    #: States shorter than this (frames) are merged into the previous state.
    min_state_frames: int = 8

    def with_(self, **changes) -> "GripperStateConfig":
        return replace(self, **changes)


def _interp_nan(d: np.ndarray) -> np.ndarray:
    """(T, H) with NaN -> linearly interpolated per column (held at the ends; all-NaN stays)."""
    d = np.array(d, dtype=np.float64)
    T = d.shape[0]
    t = np.arange(T)
    for h in range(d.shape[1]):
        ok = np.isfinite(d[:, h])
        if ok.any() and not ok.all():
            d[:, h] = np.interp(t, t[ok], d[ok, h])
    return d


def _hysteresis(d: np.ndarray, lo: np.ndarray, hi: np.ndarray, init_closed: np.ndarray) -> np.ndarray:
    """closed (T, H): switch to closed when d < lo, to open when d > hi, else keep (vectorised)."""
    T = d.shape[0]
    ev = np.where(d < lo, 1, np.where(d > hi, -1, 0))  # +1 close, -1 open
    t = np.arange(T)[:, None]
    last = np.maximum.accumulate(np.where(ev != 0, t, -1), axis=0)
    h = np.arange(d.shape[1])[None, :]
    st = ev[np.clip(last, 0, None), h]
    return np.where(last >= 0, st > 0, init_closed[None, :])


def _min_duration(closed: np.ndarray, min_frames: int) -> np.ndarray:
    """Merge runs shorter than ``min_frames`` into the previous run (the next one at the start)."""
    if min_frames <= 1:
        return closed
    out = closed.copy()
    T = out.shape[0]
    for h in range(out.shape[1]):
        c = out[:, h]
        for _ in range(3):  # short runs next to short runs: a few passes
            change = np.flatnonzero(c[1:] != c[:-1]) + 1
            starts = np.r_[0, change]
            ends = np.r_[change, T]
            short = (ends - starts) < min_frames
            if not short.any() or len(starts) == 1:
                break
            vals = c[starts].copy()
            for k in np.flatnonzero(short):
                vals[k] = vals[k - 1] if k > 0 else (vals[1] if len(vals) > 1 else vals[0])
            c = np.repeat(vals, ends - starts)
        out[:, h] = c
    return out


def otsu_threshold(x: np.ndarray, n_bins: int = 128) -> tuple[float, float, float]:
    """Otsu's two-class split of 1D values -> (threshold, mean of low class, mean of high class)."""
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size < 2 or np.ptp(x) == 0:
        v = float(x.mean()) if x.size else np.nan
        return v, v, v
    xs = np.sort(x)
    # exact Otsu over all split points of the sorted values
    n = xs.size
    cs = np.cumsum(xs)
    k = np.arange(1, n)
    m0 = cs[:-1] / k
    m1 = (cs[-1] - cs[:-1]) / (n - k)
    between = k * (n - k) * (m0 - m1) ** 2
    between = np.where(xs[1:] > xs[:-1], between, -1)
    i = int(np.argmax(between))
    return float(0.5 * (xs[i] + xs[i + 1])), float(m0[i]), float(m1[i])


def state_threshold(d: np.ndarray, w_gripper: float = 0.06) -> np.ndarray:
    """Thesis: g = 0 (closed) where d < w_gripper, else 1. NaN d -> open."""
    d = np.asarray(d, dtype=np.float64)
    return np.where(d < w_gripper, 0.0, 1.0)


def ranges_to_mask(ranges: Sequence[Sequence[int]], n_frames: int) -> np.ndarray:
    """[start, end) frame ranges -> (n_frames,) bool (clipped to the take)."""
    m = np.zeros(n_frames + 1, dtype=np.int64)
    for s, e in ranges:
        s, e = max(0, int(s)), min(n_frames, int(e))
        if e > s:
            m[s] += 1
            m[e] -= 1
    return np.cumsum(m[:-1]) > 0


def mask_to_ranges(mask: np.ndarray) -> list[list[int]]:
    """(T,) bool -> [[start, end), ...]."""
    m = np.r_[False, np.asarray(mask, bool), False].astype(np.int8)
    d = np.flatnonzero(np.diff(m))
    return [[int(a), int(b)] for a, b in zip(d[::2], d[1::2])]


def state_manual(closed_ranges: Mapping[str, Sequence[Sequence[int]]] | Sequence[Sequence[Sequence[int]]],
                 n_frames: int) -> np.ndarray:
    """Manual labels -> g (T, 2). ``closed_ranges``: {"left": [[s, e], ...], "right": [...]} (the
    annotations.json ``gripper_closed_ranges``) or a 2-sequence (left, right) of range lists."""
    if isinstance(closed_ranges, Mapping):
        per = [closed_ranges.get("left", []), closed_ranges.get("right", [])]
    else:
        per = list(closed_ranges)
    closed = np.stack([ranges_to_mask(r, n_frames) for r in per], axis=1)
    return np.where(closed, 0.0, 1.0)


def _smooth_d(d: np.ndarray, frames: int) -> np.ndarray:
    d = _interp_nan(d)
    if frames > 1:
        ok = np.isfinite(d).all(0)
        d[:, ok] = median_filter(d[:, ok], size=(frames, 1), mode="reflect")
    return d


def state_otsu(d: np.ndarray, config: GripperStateConfig | None = None) -> np.ndarray:
    """Per-hand Otsu split of the take's own fingertip distances (T, 2) with hysteresis -> g (T, 2)."""
    cfg = config or GripperStateConfig()
    ds = _smooth_d(d, cfg.smooth_frames)
    closed = np.zeros(ds.shape, dtype=bool)
    for h in range(ds.shape[1]):
        thr, m0, m1 = otsu_threshold(ds[:, h])
        if not np.isfinite(thr) or (m1 - m0) < cfg.min_depth_m:
            continue
        lo = m0 + cfg.frac_close * (m1 - m0)
        hi = m0 + cfg.frac_open * (m1 - m0)
        closed[:, h] = _hysteresis(ds[:, h:h + 1], lo, hi, np.array([ds[0, h] < thr]))[:, 0]
    closed = _min_duration(closed, cfg.min_state_frames)
    return np.where(closed, 0.0, 1.0)


def grasp_basins(d: np.ndarray, config: GripperStateConfig | None = None):
    """Water-filling basins of smoothed d (T, H) -> (level (T, H), floor (T, H), in_grasp (T, H) bool).

    level/floor are per-basin constants (NaN outside grasp basins).
    """
    cfg = config or GripperStateConfig()
    ds = _smooth_d(d, cfg.smooth_frames)
    dr = _smooth_d(d, max(cfg.rim_smooth_frames, cfg.smooth_frames))
    T, H = ds.shape
    pre = np.maximum.accumulate(dr, axis=0)
    suf = np.maximum.accumulate(dr[::-1], axis=0)[::-1]
    level_t = np.minimum(pre, suf)
    depth = level_t - ds
    inb = depth > cfg.basin_eps
    level = np.full((T, H), np.nan)
    floor = np.full((T, H), np.nan)
    in_grasp = np.zeros((T, H), dtype=bool)
    for h in range(H):
        if not np.isfinite(ds[:, h]).all():
            continue
        runs = mask_to_ranges(inb[:, h])
        for s, e in runs:
            seg = ds[s:e, h]
            lev = float(np.min(level_t[s:e, h]))  # the lower rim of the basin
            fl = float(np.percentile(seg, 10))
            if lev - fl >= cfg.min_depth_m and e - s >= cfg.min_grasp_frames:
                level[s:e, h], floor[s:e, h] = lev, fl
                in_grasp[s:e, h] = True
    return level, floor, in_grasp, ds


def state_auto(d: np.ndarray, config: GripperStateConfig | None = None) -> np.ndarray:
    """Automatic per-take open/close ("grasp basins", see the module docstring) -> g (T, 2)."""
    cfg = config or GripperStateConfig()
    level, floor, in_grasp, ds = grasp_basins(d, cfg)
    T, H = ds.shape
    lo = floor + cfg.frac_close * (level - floor)
    hi = floor + cfg.frac_open * (level - floor)
    lo = np.where(in_grasp, lo, -np.inf)   # outside a basin: never close ...
    hi = np.where(in_grasp, hi, -np.inf)   # ... and always open
    closed = _hysteresis(ds, lo, hi, np.zeros(H, dtype=bool))
    closed = _min_duration(closed, cfg.min_state_frames)
    g = np.where(closed, 0.0, 1.0)
    no_basin = ~in_grasp.any(axis=0)
    if no_basin.any():
        g_otsu = state_otsu(d, cfg)
        g[:, no_basin] = g_otsu[:, no_basin]
    return g


def gripper_state(d: np.ndarray, method: str = "auto", *, closed_ranges=None,
                  config: GripperStateConfig | None = None, **overrides) -> np.ndarray:
    """g (T, 2) (1 open, 0 closed) from fingertip distances d (T, 2).

    method: "auto" (default), "otsu", "threshold" (thesis, ``w_gripper``) or "manual"
    (``closed_ranges`` required). When ``closed_ranges`` is given it overrides any method.
    """
    cfg = config or GripperStateConfig()
    if overrides:
        cfg = cfg.with_(**overrides)
    d = np.asarray(d, dtype=np.float64)
    if closed_ranges is not None or method == "manual":
        if closed_ranges is None:
            raise ValueError("method 'manual' needs closed_ranges")
        return state_manual(closed_ranges, d.shape[0])
    if method == "auto":
        return state_auto(d, cfg)
    if method == "otsu":
        return state_otsu(d, cfg)
    if method == "threshold":
        return state_threshold(d, cfg.w_gripper)
    raise ValueError(f"unknown method {method!r}")
