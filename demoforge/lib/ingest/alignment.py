"""Depth correction of detected 3D hand joints, left/right swap repair and the outlier freeze.

Thesis section 3.1.2 (and 5.1.2), vectorised over whole takes (T frames x 2 hands).

Pipeline of :func:`align_to_depth` (every stage can be switched off in :class:`AlignmentConfig`):

1. **Swap repair** (better default; the thesis names left/right swaps as the main source of
   outliers). Done in the image, on the detector's 2D keypoints, which carry no depth error: per
   frame the two slots are assigned to the two physical hands by comparing the costs of the two
   assignments (labelled-left -> previous left and labelled-right -> previous right, versus the
   crossed assignment), costs = pixel distance of each hand's 2D centroid to the last repaired
   centroid of that hand. The crossed assignment wins when it is cheaper by ``swap_margin_px``.
   A frame with a single detected hand assigns it to the closer previous hand on the same rule.
   This is a tight scalar loop over T (a few microseconds per frame). Because the detector is
   right most of the time, the take-level labelling that disagrees with the detector on fewer
   frames is kept (so a take whose first frames are swapped is still repaired).
2. **Depth anchor translation** (thesis 3.1.2): the anchors' 2D positions (``joints_px`` when
   given -- the accurate 2D of the detector; else the projection of the 3D prediction) are looked
   up in the depth map with a robust window median (:func:`read_depth_robust`), back-projected,
   ``X' = Z' K^-1 [u, v, 1]``, and moved ``surface_offset_m`` further along the viewing ray: the
   depth camera sees the skin, the joints lie inside the finger/palm (about one flesh radius
   deeper). ``dt = X' - X_pred`` per anchor. Occluders (the held object) only make a reading
   shallower and silhouette edges (background) only deeper, so the anchors whose depth
   correction lies within ``anchor_outlier_m`` of the ``anchor_depth_quantile`` (0.8: trust the
   deeper readings) of the hand's anchors are kept and their translations combined by the
   component-wise median; the result is applied to all 21 joints.
   A temporal check then rejects frames whose corrected root depth differs from the median of
   the ``depth_median_frames`` neighbouring frames by more than ``depth_outlier_m``
   (``depth_outlier`` flag: a hand mostly hidden behind an object).
   Frames where a detected hand has fewer than ``min_anchors`` usable anchors are flagged
   ``no_depth``. For them and for depth outliers the corrected root depth is interpolated in
   time from the trusted frames and the hand is moved along its root's viewing ray to it (the
   direction of the detector's error). This replaces "keep the previous translation": the
   detector's depth error jitters by ~2 % (several cm) from frame to frame, the true hand's
   depth does not.
3. **Scale correction** (optional, default per take): the detector's hand size error leaves
   an error proportional to the distance from the anchors after translation. The 2D keypoints fix
   it: at the corrected depth, the projected hand should have the 2D spread of ``joints_px``. The
   least-squares ratio of the two spreads per frame gives the scale, its median over the take
   (per physical hand) is divided out about the anchors' centre. Needs ``joints_px``.
4. **Outlier freeze** (thesis 3.1.2): per hand, the mean over the 21 joints of the squared
   Euclidean distance to the last accepted keypoints (``MSE``, m^2). Above
   ``outlier_mse_threshold`` the frame is an outlier and the last accepted keypoints are kept
   until a frame comes back below the threshold. Unlike the thesis the freeze is capped at
   ``max_freeze_frames`` (then the current detection is accepted: a real fast motion must not lock
   the hand forever).
5. **Filling**: hands not detected (``present`` False) and frozen frames are filled from the
   accepted frames: ``fill="interpolate"`` (linear between the neighbouring accepted frames, held
   at the ends; default) or ``fill="hold"`` (the thesis: keep the previous accepted frame, the
   first accepted frame before it). A hand never detected in the take stays NaN. With
   ``max_gap_frames`` only runs of at most that many undetected frames are filled (the ingest sets
   it from the hand tracker, demoforge.lib.perception.tracking); longer gaps stay NaN (not present).

The output never contains NaN for a frame where a hand was detected, nor anywhere for a hand
that was detected at least once.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from demoforge.lib.geometry import backproject, project_points
from demoforge.lib.perception.robust import nan_median
from demoforge.lib.perception.tracking import bounded_fill_mask
from demoforge.lib.perception.track_repair import fill_gaps, freeze_outliers, repair_swaps

__all__ = [
    "AlignmentConfig",
    "AlignmentResult",
    "read_depth_robust",
    "backproject",
    "project",
    "nan_median",
    "nan_quantile",
    "repair_swaps",
    "freeze_outliers",
    "fill_gaps",
    "align_to_depth",
]

N_JOINTS = 21


# --------------------------------------------------------------------------- config / result


@dataclass(frozen=True)
class AlignmentConfig:
    """Parameters of :func:`align_to_depth` (defaults measured on the synthetic takes)."""

    #: Joints whose depth is read (palm and thumb base: large, rarely occluded; thesis: 1 or 2).
    anchors: tuple[int, ...] = (0, 1, 2, 5, 9, 13, 17)
    #: Side of the square pixel window of the robust depth read (odd).
    window: int = 5
    #: Minimum number of valid depth pixels in the window for a reading.
    min_valid: int = 3
    #: Minimum number of anchors with a reading for a frame to count as having depth.
    min_anchors: int = 1
    #: Distance (m) from the seen skin surface to the joint centre along the viewing ray: one
    #: value for all anchors or a 21-tuple per joint (measured on the synthetic takes: median
    #: joint-minus-surface depth of the visible anchors, about the flesh radius).
    surface_offset_m: float | tuple[float, ...] = 0.0127
    #: "ray": the translation is constrained to the root's viewing ray through its 2D keypoint
    #: (the detector's 2D is right, its depth wrong; each anchor votes with its depth only);
    #: "free": the thesis's full 3D dt = X' - X_pred per anchor.
    translation: str = "free"
    #: Temporal check: a frame whose corrected root depth differs from the median over
    #: ``depth_median_frames`` neighbouring frames by more than this (m) is a depth outlier
    #: (anchors occluded by an object) and is treated like a frame without depth. None = off.
    depth_outlier_m: float | None = 0.02
    depth_median_frames: int = 9
    #: How per-anchor translations are combined: "median" (component-wise) or "mean".
    combine: str = "median"
    #: Anchor readings whose translation's depth (z) differs from the hand's median by more
    #: than this (m) are dropped before combining (occluders, background); inf = keep all.
    anchor_outlier_m: float = 0.015
    #: Centre of that window: this quantile of the anchors' depth corrections (0.5 = median;
    #: higher trusts the deeper readings: occluders only make readings shallower).
    anchor_depth_quantile: float = 0.8
    #: Hand-size correction from the 2D keypoints: "take" (median over the take, per hand),
    #: "frame" (per frame) or "none" (the thesis: translation only).
    scale_correction: str = "take"
    #: Left/right swap repair on the 2D keypoints.
    repair_swaps: bool = True
    #: A swap is repaired when the crossed assignment is cheaper by at least this (px).
    swap_margin_px: float = 10.0
    #: Thesis outlier freeze: threshold on the MSE (m^2, mean over joints of the squared distance)
    #: to the last accepted keypoints; 2.5e-3 m^2 = 5 cm RMS jump in one frame. inf = off.
    outlier_mse_threshold: float = 2.5e-3
    #: A freeze longer than this (frames) is ended by accepting the current detection.
    max_freeze_frames: int = 15
    #: How frozen and missing frames are filled: "interpolate" or "hold" (the thesis).
    fill: str = "interpolate"
    #: Longest run of frames filled (between accepted frames, or before the first / after the last
    #: one); longer gaps stay empty (NaN, not present). None = fill everything (the thesis).
    max_gap_frames: int | None = None

    def __post_init__(self) -> None:
        if self.window < 1 or self.window % 2 == 0:
            raise ValueError(f"window must be a positive odd integer, got {self.window}")
        if not self.anchors or any(not 0 <= a < N_JOINTS for a in self.anchors):
            raise ValueError(f"anchors must be joint indices in [0, 21), got {self.anchors}")
        if self.combine not in ("median", "mean"):
            raise ValueError(f"combine must be 'median' or 'mean', got {self.combine!r}")
        if self.scale_correction not in ("take", "frame", "none"):
            raise ValueError(f"scale_correction must be 'take', 'frame' or 'none', got {self.scale_correction!r}")
        if self.translation not in ("ray", "free"):
            raise ValueError(f"translation must be 'ray' or 'free', got {self.translation!r}")
        if self.fill not in ("interpolate", "hold"):
            raise ValueError(f"fill must be 'interpolate' or 'hold', got {self.fill!r}")
        if self.max_gap_frames is not None and self.max_gap_frames < 0:
            raise ValueError(f"max_gap_frames must be >= 0 or None, got {self.max_gap_frames}")
        if self.min_anchors < 1 or self.min_valid < 1 or self.max_freeze_frames < 0:
            raise ValueError("min_anchors and min_valid must be >= 1, max_freeze_frames >= 0")

    @classmethod
    def thesis(cls, **overrides) -> "AlignmentConfig":
        """The thesis's method: one translation per hand, no swap repair, no scale, hold-freeze."""
        base = dict(anchors=(2,), combine="median", translation="free", depth_outlier_m=None, surface_offset_m=0.0, anchor_outlier_m=np.inf,
                    scale_correction="none", repair_swaps=False, fill="hold",
                    max_freeze_frames=10**9)
        base.update(overrides)
        return cls(**base)

    def with_(self, **changes) -> "AlignmentConfig":
        return replace(self, **changes)


@dataclass
class AlignmentResult:
    """Output of :func:`align_to_depth`. Slot order: 0 = left, 1 = right (after swap repair)."""

    #: (T, 2, 21, 3) final camera-frame joints: aligned, swap-repaired, frozen and filled.
    joints_cam: np.ndarray
    #: (T, 2, 21, 3) depth-aligned joints before freeze/fill (NaN where not detected).
    joints_aligned: np.ndarray
    #: (T, 2, 3) anchor translation dt per frame and hand, before the scale correction (NaN
    #: where not detected).
    translation: np.ndarray
    #: (T, 2) hand-size factor divided out (1 = none; NaN where not detected).
    scale: np.ndarray
    #: (T, 2) bitmask of the joints whose depth was used (bit j = joint j).
    anchors_used: np.ndarray
    #: (T, 2) number of anchors with a valid depth reading (before outlier rejection).
    n_anchors_valid: np.ndarray
    #: (T, 2) the hand was detected (after swap repair).
    detected: np.ndarray
    #: (T, 2) the output holds finite joints.
    present: np.ndarray
    #: (T, 2) input slot that each output hand comes from (0/1; swap repair), -1 if none.
    source_slot: np.ndarray
    #: (T, 2) flags.
    no_depth: np.ndarray
    #: (T, 2) depth reading rejected by the temporal check (filled like no_depth frames).
    depth_outlier: np.ndarray
    outlier_frozen: np.ndarray
    swap_repaired: np.ndarray
    filled_missing: np.ndarray
    config: AlignmentConfig = field(default_factory=AlignmentConfig)

    @property
    def swap_frames(self) -> np.ndarray:
        """(T,) frames whose left/right labels were swapped back."""
        return self.swap_repaired.any(axis=1)

    @property
    def flags(self) -> dict[str, np.ndarray]:
        return {"no_depth": self.no_depth, "depth_outlier": self.depth_outlier,
                "outlier_frozen": self.outlier_frozen,
                "swap_repaired": self.swap_repaired, "filled_missing": self.filled_missing}


# --------------------------------------------------------------------------- camera helpers


# Camera helpers live in demoforge.lib.geometry; re-exported here under the names this module always used.
project = project_points


def nan_quantile(x: np.ndarray, q: float, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Quantile (linear interpolation, numpy's default) ignoring NaN via one sort -> (value, count)."""
    x = np.moveaxis(np.asarray(x, dtype=np.float64), axis, -1)
    n = np.sum(~np.isnan(x), axis=-1)
    if x.shape[-1] == 0:
        return np.full(x.shape[:-1], np.nan), n
    s = np.sort(x, axis=-1)
    pos = q * np.maximum(n - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    a = np.take_along_axis(s, lo[..., None], -1)[..., 0]
    b = np.take_along_axis(s, hi[..., None], -1)[..., 0]
    val = a + (pos - lo) * (b - a)
    return np.where(n > 0, val, np.nan), n


# --------------------------------------------------------------------------- robust depth read


def read_depth_robust(depth: np.ndarray, uv: np.ndarray, window: int = 5,
                      min_valid: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Median depth in a ``window`` x ``window`` pixel window around each uv.

    depth: (H, W) or (T, H, W) in metres, 0 or NaN = invalid (a uint16 millimetre image must be
    converted by the caller). uv: (..., 2) pixel coordinates (u = column, v = row; pixel centres
    at integers, rounded to the nearest pixel); for a (T, H, W) depth uv must be (T, ..., 2) and
    point i of frame t reads depth[t]. Invalid pixels and pixels outside the image are skipped.
    Returns (z (...), n_valid (...) int): z is NaN where fewer than ``min_valid`` pixels are valid
    (or uv is NaN). Vectorised: one fancy-index gather of all windows.
    """
    d = np.asarray(depth)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape[-1] != 2:
        raise ValueError(f"uv must have shape (..., 2), got {uv.shape}")
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be a positive odd integer, got {window}")
    if d.ndim == 2:
        frame = None
        H, W = d.shape
    elif d.ndim == 3:
        if uv.ndim < 2 or uv.shape[0] != d.shape[0]:
            raise ValueError(f"for depth (T, H, W) uv must be (T, ..., 2); got depth {d.shape}, uv {uv.shape}")
        H, W = d.shape[1:]
        frame = np.arange(d.shape[0]).reshape((-1,) + (1,) * (uv.ndim - 2) + (1,))
    else:
        raise ValueError(f"depth must be (H, W) or (T, H, W), got {d.shape}")
    ok_uv = np.isfinite(uv).all(-1)
    uvr = np.rint(np.where(ok_uv[..., None], uv, -1e9)).clip(-1e9, 1e9).astype(np.int64)
    r = window // 2
    off = np.arange(-r, r + 1)
    du = np.tile(off, window)
    dv = np.repeat(off, window)
    cols = uvr[..., 0:1] + du  # (..., w*w)
    rows = uvr[..., 1:2] + dv
    inside = (cols >= 0) & (cols < W) & (rows >= 0) & (rows < H)
    cc = np.clip(cols, 0, W - 1)
    rr = np.clip(rows, 0, H - 1)
    vals = (d[rr, cc] if frame is None else d[frame, rr, cc]).astype(np.float64)
    good = inside & (vals > 0) & np.isfinite(vals)
    vals = np.where(good, vals, np.nan)
    z, n = nan_median(vals, axis=-1)
    z = np.where((n >= min_valid) & ok_uv, z, np.nan)
    return z, np.where(ok_uv, n, 0)


# --------------------------------------------------------------------------- main entry


def _ffill_bfill(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Per hand: values (T, 2, C) at ~ok frames replaced by the previous ok frame (else next)."""
    T = values.shape[0]
    t = np.arange(T)[:, None]
    prev = np.maximum.accumulate(np.where(ok, t, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(ok, t, T)[::-1], axis=0)[::-1]
    src = np.where(prev >= 0, prev, np.where(nxt < T, nxt, 0))
    out = values[src, np.arange(2)[None, :]]
    none = (prev < 0) & (nxt >= T)
    out[none] = np.nan
    return out


def _anchor_translation(X: np.ndarray, P2: np.ndarray, z: np.ndarray, uv: np.ndarray, detected: np.ndarray,
                        K: np.ndarray, cfg: AlignmentConfig):
    """Step 2: each detected hand's translation (T, 2, 3) onto the depth read at its anchors, the
    occluded anchors' and the temporally implausible readings left out, frames without a trusted
    reading moved along the root's viewing ray to the depth interpolated in time.
    -> (translation, valid anchors (T, 2, A), valid anchors per hand, no_depth, depth_outlier, anchors_used)."""
    T = X.shape[0]
    anchors = np.asarray(cfg.anchors, dtype=np.int64)
    ray = backproject(uv, np.ones(uv.shape[:-1]), K)              # (T, 2, A, 3), z = 1
    ray_unit = ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    off = np.asarray(cfg.surface_offset_m, dtype=np.float64)
    off = off[anchors] if off.ndim == 1 else np.full(anchors.shape, float(off))
    Xs = ray * z[..., None] + off[:, None] * ray_unit             # joint centre behind the skin
    dt_a = Xs - X[:, :, anchors, :]                              # (T, 2, A, 3), NaN if no depth
    valid_a = np.isfinite(z)
    n_valid = valid_a.sum(-1)
    if np.isfinite(cfg.anchor_outlier_m):
        zref, _ = nan_quantile(dt_a[..., 2], cfg.anchor_depth_quantile, axis=-1)
        valid_a = valid_a & (np.abs(dt_a[..., 2] - zref[..., None]) <= cfg.anchor_outlier_m)
    dt_a = np.where(valid_a[..., None], dt_a, np.nan)
    if cfg.translation == "ray":
        # the detector's error is a shift along the root's viewing ray: one unknown per hand,
        # k_a = depth difference of anchor a / z-component of the root ray
        root_px = P2[:, :, 0, :]
        u_root = backproject(root_px, np.ones(root_px.shape[:-1]), K)
        u_root = u_root / np.linalg.norm(u_root, axis=-1, keepdims=True)          # (T, 2, 3)
        k_a = dt_a[..., 2] / u_root[:, :, None, 2]
        dt_a = k_a[..., None] * u_root[:, :, None, :]
    if cfg.combine == "median":
        dt, _ = nan_median(np.moveaxis(dt_a, 2, -1), axis=-1)   # (T, 2, 3)
    else:
        with np.errstate(invalid="ignore"):
            cnt = valid_a.sum(-1)[..., None]
            dt = np.where(cnt > 0, np.nansum(dt_a, axis=2) / np.maximum(cnt, 1), np.nan)
    has_depth = detected & (valid_a.sum(-1) >= cfg.min_anchors) & np.isfinite(dt).all(-1)
    no_depth = detected & ~has_depth
    bits = (1 << anchors.astype(np.int64))
    anchors_used = np.where(detected, np.sum(np.where(valid_a, bits, 0), axis=-1), 0).astype(np.int64)
    # temporal check of the corrected root depth: occluded anchors give depths far off their
    # neighbours' (the true hand moves smoothly even though the detector's error jitters)
    root = X[:, :, 0, :]
    z_al = np.where(has_depth, root[..., 2] + dt[..., 2], np.nan)             # (T, 2)
    depth_outlier = np.zeros_like(has_depth)
    if cfg.depth_outlier_m is not None and np.isfinite(cfg.depth_outlier_m) and T > 2:
        w = max(3, int(cfg.depth_median_frames) | 1)
        pad = np.pad(z_al, ((w // 2, w // 2), (0, 0)), constant_values=np.nan)
        win = np.lib.stride_tricks.sliding_window_view(pad, w, axis=0)          # (T, 2, w)
        zmed_t, cnt = nan_median(win, axis=-1)
        depth_outlier = has_depth & (cnt >= 3) & (np.abs(z_al - zmed_t) > cfg.depth_outlier_m)
    ok_depth = has_depth & ~depth_outlier
    # frames without a trusted reading: root depth interpolated in time from trusted frames,
    # the hand moved along its root's viewing ray to that depth (the detector's error direction)
    z_fill = fill_gaps(np.where(ok_depth, z_al, np.nan)[..., None], ok_depth, "interpolate")[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        lam = z_fill / root[..., 2]
    dt_fill = (lam - 1.0)[..., None] * root
    dt = np.where(ok_depth[..., None], dt, dt_fill)
    dt = np.where(detected[..., None], dt, np.nan)
    # no depth anywhere in the take for this hand: keep the raw prediction (translation 0), flagged
    dt = np.where(detected[..., None] & ~np.isfinite(dt), 0.0, dt)
    return dt, valid_a, n_valid, no_depth, depth_outlier, anchors_used


def _scale_correction(Xa: np.ndarray, P2: np.ndarray, valid_a: np.ndarray, detected: np.ndarray, K: np.ndarray,
                      cfg: AlignmentConfig) -> tuple[np.ndarray, np.ndarray]:
    """Step 3: each hand scaled about its anchors' centre so that its projection spans the detector's 2D
    keypoints (per frame, or one factor per take). -> (joints (T, 2, 21, 3), scale (T, 2))."""
    T = Xa.shape[0]
    anchors = np.asarray(cfg.anchors, dtype=np.int64)
    va = valid_a[..., None]
    centre = np.sum(np.where(va, Xa[:, :, anchors, :], 0.0), axis=2) / np.maximum(va.sum(axis=2), 1)
    centre = np.where(va.any(axis=2), centre, np.nan)
    centre = np.where(np.isfinite(centre), centre, Xa[:, :, anchors, :].mean(axis=2))
    proj = project(Xa, K)
    pa = proj - proj.mean(axis=2, keepdims=True)
    qa = P2 - P2.mean(axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_f = np.sum(pa * qa, axis=(2, 3)) / np.sum(qa * qa, axis=(2, 3))
    c_f = np.where(detected & np.isfinite(c_f) & (c_f > 0.5) & (c_f < 2.0), c_f, np.nan)
    if cfg.scale_correction == "take":
        med, cnt = nan_median(c_f.T, axis=-1)
        c_use = np.where(cnt > 0, med, 1.0)[None, :].repeat(T, 0)
    else:
        c_use = _ffill_bfill(c_f[..., None], np.isfinite(c_f))[..., 0]
        c_use = np.where(np.isfinite(c_use), c_use, 1.0)
    c_use = np.where(detected, c_use, np.nan)
    Xa = centre[:, :, None, :] + (Xa - centre[:, :, None, :]) / c_use[..., None, None]
    Xa = np.where(detected[..., None, None], Xa, np.nan)
    return Xa, c_use


def align_to_depth(joints_cam: np.ndarray, depth: np.ndarray | None, K: np.ndarray,
                   joints_px: np.ndarray | None = None, config: AlignmentConfig | None = None,
                   *, anchor_depth: np.ndarray | None = None, **overrides) -> AlignmentResult:
    """Depth-align, swap-repair, freeze and fill one take's detected hands (see the module doc).

    joints_cam: (T, 2, 21, 3) detected camera-frame joints (m), slot 0 = labelled left; an
        undetected hand is all NaN. depth: (T, H, W) metres (0/NaN invalid), or None when
        ``anchor_depth`` is given. K: (3, 3). joints_px: (T, 2, 21, 2) the detector's 2D keypoints
        (recommended: accurate 2D). anchor_depth: optional precomputed (T, 2, A) robust depth at
        the anchors' 2D positions *in input slot order* (lets a caller stream depth in chunks).
        ``overrides`` are :class:`AlignmentConfig` fields (e.g. ``anchors=(1, 2)``, ``window=5``).
    """
    cfg = (config or AlignmentConfig())
    if overrides:
        cfg = cfg.with_(**overrides)
    X = np.asarray(joints_cam, dtype=np.float64)
    if X.ndim != 4 or X.shape[1:] != (2, N_JOINTS, 3):
        raise ValueError(f"joints_cam must be (T, 2, 21, 3), got {X.shape}")
    T = X.shape[0]
    K = np.asarray(K, dtype=np.float64)
    present_in = np.isfinite(X).all(axis=(2, 3))
    if joints_px is not None:
        P2 = np.asarray(joints_px, dtype=np.float64)
        if P2.shape != (T, 2, N_JOINTS, 2):
            raise ValueError(f"joints_px must be (T, 2, 21, 2), got {P2.shape}")
    else:
        P2 = project(X, K)
    anchors = np.asarray(cfg.anchors, dtype=np.int64)

    # --- robust depth at the anchors (input slot order) ---------------------------------------
    uv = P2[:, :, anchors, :]                                    # (T, 2, A, 2)
    if anchor_depth is None:
        if depth is None:
            raise ValueError("give depth or anchor_depth")
        z, _ = read_depth_robust(depth, uv, cfg.window, cfg.min_valid)
    else:
        z = np.asarray(anchor_depth, dtype=np.float64)
        if z.shape != uv.shape[:-1]:
            raise ValueError(f"anchor_depth must be {uv.shape[:-1]}, got {z.shape}")
    z = np.where(present_in[..., None], z, np.nan)

    # --- 1. swap repair on 2D --------------------------------------------------------------
    if cfg.repair_swaps:
        cen = np.where(present_in[..., None], np.nanmean(np.where(present_in[..., None, None], P2, 0.0), axis=2), np.nan)
        swapped = repair_swaps(cen, present_in, cfg.swap_margin_px)
    else:
        swapped = np.zeros(T, dtype=bool)
    src = np.where(swapped[:, None], np.array([1, 0]), np.array([0, 1]))
    tt = np.arange(T)[:, None]
    X, P2, z, uv = X[tt, src], P2[tt, src], z[tt, src], uv[tt, src]
    detected = present_in[tt, src]
    swap_flag = swapped[:, None] & detected
    source_slot = np.where(detected, src, -1)

    # --- 2. anchor translation ---------------------------------------------------------------
    dt, valid_a, n_valid, no_depth, depth_outlier, anchors_used = _anchor_translation(X, P2, z, uv, detected, K, cfg)
    Xa = X + dt[:, :, None, :]

    # --- 3. scale correction from the 2D keypoints ---------------------------------------------
    scale = np.where(detected, 1.0, np.nan)
    if cfg.scale_correction != "none" and joints_px is not None:
        Xa, scale = _scale_correction(Xa, P2, valid_a, detected, K, cfg)

    # --- 4. freeze and 5. fill ------------------------------------------------------------------
    frozen = freeze_outliers(Xa, detected, cfg.outlier_mse_threshold, cfg.max_freeze_frames)
    good = detected & ~frozen
    if cfg.fill == "hold":
        # the thesis: hold the last accepted keypoints (the first accepted ones before them)
        out = fill_gaps(Xa, good, "hold")
    else:
        out = fill_gaps(Xa, good, "interpolate")
    if cfg.max_gap_frames is not None:
        # bounded on missing detections only: frozen frames were detected and keep their held values
        out = np.where(bounded_fill_mask(detected, cfg.max_gap_frames)[..., None, None], out, np.nan)
    present_out = np.isfinite(out).all(axis=(2, 3))
    filled_missing = present_out & ~detected
    return AlignmentResult(
        joints_cam=out, joints_aligned=Xa, translation=dt, scale=scale,
        anchors_used=anchors_used, n_anchors_valid=np.where(detected, n_valid, 0),
        detected=detected, present=present_out, source_slot=source_slot,
        no_depth=no_depth, depth_outlier=depth_outlier, outlier_frozen=frozen, swap_repaired=swap_flag,
        filled_missing=filled_missing, config=cfg,
    )
