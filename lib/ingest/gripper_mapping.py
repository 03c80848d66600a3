"""Hand joints -> two-finger gripper poses and open/close states (thesis section 3.1.3 and 5.2).

Pose (:func:`hand_to_gripper`), exactly the thesis's heuristic, completed to a full frame:

* position p = (p_thumb_tip(4) + p_index_tip(8)) / 2;
* approach axis: the thesis's Rodrigues rotation R_rod maps the reference axis (gripper z, the
  approach axis of docs/architecture.md) onto the unit vector from b = (p_0 + p_1) / 2 to a = p. Rodrigues
  alone leaves the twist about z free; it is fixed with the docs/architecture.md convention: x = thumb tip ->
  index tip made orthogonal to z, y = z x x, i.e. R = R_rod @ Rz(psi) with psi the angle from
  R_rod's x to that direction. Where the tips (nearly) coincide (their orthogonalised separation
  < ``min_tip_separation``) the x direction of the nearest earlier valid frame (projected
  orthogonal to the current z) is used, else the first later one, else R_rod's own x.

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

Optional smoothing (:func:`smooth_poses`, off by default) filters positions and rotations only
within constant-state segments, so grasp and release instants stay sharp.

Grasp stabilisation (:func:`stabilize_grasps`, mode "pose" by default): while a
hand is closed the grasp is rigid, so the pinch frame is fixed in the hand's frame; the hand's
rigid motion is fitted over all 21 joints (Kabsch) and the pinch transform averaged robustly over
the closed interval. On the six ingested synthetic takes it cut the median twist error about the
approach axis on closed frames from 4-32 deg to 2-4 deg (90th percentile from 10-128 deg to
5-8 deg). Table floor (:func:`clamp_above_table`): pinch points are kept 10 mm above the table
top. Robot success on the 20 sampled episodes per task (the same episode ids, re-generated from
the re-mapped take): 16/120 as mapped, 90/120 with the twist prior, 110/120 with both (trash,
paper, open_container, mix_bowl 20/20 each, empty_vase 12/20, pouring 18/20).
Mode "pose" (also the pinch position and approach axis from the hand's rigid motion) against
"twist", 40 sampled episodes per task from 10,000-episode databases of each task's seed-0 take
(ingest, augment and simulate each with that prior): pose 233/240 (40/40 on five tasks,
empty_vase 33/40 with its original episode), twist 216/240 (pouring 36/40, empty_vase 20/40 with
its original failing on the thin stem, the rest 40/40). Around the thin-stem grasp the mapped pinch
moves 3-21 mm from one frame to the next where the scripted hand moves 0-6 mm; a moving-average
smoothing (window 5) instead made empty_vase worse (7/40 with twist, 8/40 with pose).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
from scipy.ndimage import median_filter, uniform_filter1d

from demoforge.lib.geometry import matrix_to_quat, quat_to_matrix, rotation_between_vectors

__all__ = [
    "GripperStateConfig",
    "hand_to_gripper",
    "gripper_rotation",
    "gripper_state",
    "state_threshold",
    "state_manual",
    "state_auto",
    "state_otsu",
    "grasp_basins",
    "otsu_threshold",
    "ranges_to_mask",
    "mask_to_ranges",
    "smooth_poses",
    "stabilize_grasps",
    "GraspStabilizationConfig",
    "clamp_above_table",
    "PINCH_MIN_HEIGHT",
    "to_pose8",
    "REFERENCE_AXIS",
]

#: The gripper's approach axis in its own frame (what Rodrigues rotates onto b -> a).
REFERENCE_AXIS = np.array([0.0, 0.0, 1.0])
THUMB_TIP, INDEX_TIP = 4, 8
#: The rigid part of the hand: wrist, thumb CMC and the four finger knuckles (MCP).
PALM_JOINTS = (0, 1, 5, 9, 13, 17)


# --------------------------------------------------------------------------- pose


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n, n[..., 0]


def gripper_rotation(joints: np.ndarray, min_tip_separation: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrices (T, ..., 3, 3) of the gripper frame for joints (T, ..., 21, 3).

    Returns (R, degenerate): degenerate (T, ...) marks frames whose x axis was borrowed from a
    neighbouring frame (tips closer than ``min_tip_separation`` after removing the z component).
    Frames with non-finite joints give NaN.
    """
    j = np.asarray(joints, dtype=np.float64)
    tip_t, tip_i = j[..., THUMB_TIP, :], j[..., INDEX_TIP, :]
    a = 0.5 * (tip_t + tip_i)
    b = 0.5 * (j[..., 0, :] + j[..., 1, :])
    z, zn = _unit(a - b)
    finite = np.isfinite(j).all(axis=(-1, -2)) & (zn > 1e-9)
    z = np.where(finite[..., None], z, REFERENCE_AXIS)
    # Thesis: Rodrigues rotation of the reference axis onto b -> a.
    R_rod = rotation_between_vectors(np.broadcast_to(REFERENCE_AXIS, z.shape), z)
    v = tip_i - tip_t
    v = v - np.sum(v * z, axis=-1, keepdims=True) * z
    x, xn = _unit(v)
    ok = finite & (xn >= min_tip_separation)
    degenerate = finite & ~ok
    if degenerate.any() and j.ndim >= 3:
        # borrow the x direction of the nearest earlier (else later) valid frame, along axis 0
        T = j.shape[0]
        t = np.arange(T).reshape((T,) + (1,) * (ok.ndim - 1))
        prev = np.maximum.accumulate(np.where(ok, t, -1), axis=0)
        nxt = np.minimum.accumulate(np.where(ok, t, T)[::-1], axis=0)[::-1]
        src = np.where(prev >= 0, prev, np.where(nxt < T, nxt, -1))
        x_src = np.take_along_axis(np.where(ok[..., None], x, 0.0), np.clip(src, 0, None)[..., None], axis=0)
        x_b = x_src - np.sum(x_src * z, axis=-1, keepdims=True) * z
        x_b, xbn = _unit(x_b)
        use_b = degenerate & (src >= 0) & (xbn > 1e-6)
        x = np.where(use_b[..., None], x_b, x)
        ok = ok | use_b
    # remaining degenerate frames: R_rod's own x axis (pure thesis rotation)
    x = np.where(ok[..., None], x, R_rod[..., :, 0])
    # R = R_rod @ Rz(psi): psi = angle from R_rod's x to x about z
    x0, y0 = R_rod[..., :, 0], R_rod[..., :, 1]
    psi = np.arctan2(np.sum(x * y0, -1), np.sum(x * x0, -1))
    c, s = np.cos(psi), np.sin(psi)
    Rz = np.zeros(psi.shape + (3, 3))
    Rz[..., 0, 0], Rz[..., 0, 1], Rz[..., 1, 0], Rz[..., 1, 1], Rz[..., 2, 2] = c, -s, s, c, 1.0
    R = R_rod @ Rz
    R = np.where(finite[..., None, None], R, np.nan)
    return R, degenerate


def hand_to_gripper(joints_world: np.ndarray, min_tip_separation: float = 1e-3
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Thesis 3.1.3 mapping: joints (T, 2, 21, 3) -> (pose7 (T, 2, 7) [x y z qx qy qz qw], d (T, 2)).

    Works for any leading shape (..., 21, 3); the degenerate-x fallback borrows along axis 0.
    d = |p_index_tip - p_thumb_tip| (m). Hands with non-finite joints give NaN rows.
    """
    j = np.asarray(joints_world, dtype=np.float64)
    if j.shape[-2:] != (21, 3):
        raise ValueError(f"joints must be (..., 21, 3), got {j.shape}")
    pos = 0.5 * (j[..., THUMB_TIP, :] + j[..., INDEX_TIP, :])
    d = np.linalg.norm(j[..., INDEX_TIP, :] - j[..., THUMB_TIP, :], axis=-1)
    R, _ = gripper_rotation(j, min_tip_separation)
    finite = np.isfinite(R).all(axis=(-1, -2))
    q = matrix_to_quat(np.where(finite[..., None, None], R, np.eye(3)))
    q = np.where(finite[..., None], q, np.nan)
    return np.concatenate([pos, q], axis=-1), d


def to_pose8(pose7: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(T, 2, 7) poses and (T, 2) gripper states (1 open, 0 closed) -> (T, 2, 8)."""
    p = np.asarray(pose7, dtype=np.float64)
    g = np.broadcast_to(np.asarray(g, dtype=np.float64), p.shape[:-1])
    return np.concatenate([p, g[..., None]], axis=-1)


# --------------------------------------------------------------------------- open / close


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


# --------------------------------------------------------------------------- smoothing


def smooth_poses(pose7: np.ndarray, g: np.ndarray, window: int = 5) -> np.ndarray:
    """Moving-average smoothing of positions and rotations within constant-g segments.

    pose7 (T, 2, 7), g (T, 2). Each hand's take is cut at every open/close transition (and at
    non-finite frames); inside a segment positions are box-filtered (``window`` frames, shrinking
    at the segment ends) and rotations are averaged as matrices (chordal mean, re-orthonormalised
    by SVD), so nothing is smoothed across a grasp or release instant.
    """
    p = np.asarray(pose7, dtype=np.float64).copy()
    g = np.asarray(g)
    if window <= 1:
        return p
    T = p.shape[0]
    R = quat_to_matrix(np.where(np.isfinite(p[..., 3:]), p[..., 3:], [0, 0, 0, 1.0]))
    out = p.copy()
    half = window // 2
    for h in range(p.shape[1]):
        ok = np.isfinite(p[:, h]).all(-1)
        seg_id = np.cumsum(np.r_[True, (g[1:, h] != g[:-1, h]) | (ok[1:] != ok[:-1])])
        # windowed sums restricted to the segment: cumulative sums with segment masking
        data = np.concatenate([p[:, h, :3], R[:, h].reshape(T, 9)], axis=1)
        data = np.where(ok[:, None], data, 0.0)
        cs = np.vstack([np.zeros((1, 12)), np.cumsum(data, axis=0)])
        t = np.arange(T)
        lo = np.clip(t - half, 0, T - 1)
        hi = np.clip(t + half, 0, T - 1)
        # shrink the window to stay in the same segment
        seg_start = np.r_[0, np.flatnonzero(np.diff(seg_id)) + 1]
        seg_end = np.r_[seg_start[1:], T]
        sid = seg_id - 1
        lo = np.maximum(lo, seg_start[sid])
        hi = np.minimum(hi, seg_end[sid] - 1)
        n = (hi - lo + 1)[:, None]
        mean = (cs[hi + 1] - cs[lo]) / n
        Rm = mean[:, 3:].reshape(T, 3, 3)
        U, _, Vt = np.linalg.svd(Rm)
        D = np.ones((T, 3))
        D[:, 2] = np.sign(np.linalg.det(U @ Vt))
        Rs = (U * D[:, None, :]) @ Vt
        q = matrix_to_quat(np.where(ok[:, None, None], Rs, np.eye(3)))
        out[:, h, :3] = np.where(ok[:, None], mean[:, :3], np.nan)
        out[:, h, 3:] = np.where(ok[:, None], q, np.nan)
    return out


# --------------------------------------------------------------------------- grasp stabilisation


@dataclass(frozen=True)
class GraspStabilizationConfig:
    """Parameters of :func:`stabilize_grasps` (see its docstring).

    mode: "twist" (replace only the twist about the approach axis), "pose" (rotation and
    position from the hand's rigid motion and the grasp's mean pinch transform) or "off".
    """

    mode: str = "pose"
    #: Closed intervals with fewer valid frames than this are left as they are.
    min_frames: int = 5
    #: Frames before a grasp / after a release over which the result is blended in / out (the
    #: gripper starts closing before g switches: gripper.py close_lead_s = 0.3 s = 9 frames at 30 fps).
    blend_frames: int = 9
    #: Iterations of the robust (Weiszfeld, L1) mean of the relative rotations and positions.
    robust_iterations: int = 5
    #: Joints of the hand's rigid-motion fit: "all" 21, or "palm" (wrist, thumb CMC and the four
    #: knuckles, rigid also while the fingers open in the blends).
    hand_points: str = "all"

    def __post_init__(self):
        if self.mode not in ("twist", "pose", "off"):
            raise ValueError(f"GraspStabilizationConfig.mode must be 'twist', 'pose' or 'off', got {self.mode!r}")
        if self.hand_points not in ("all", "palm"):
            raise ValueError(f"GraspStabilizationConfig.hand_points must be 'all' or 'palm', got {self.hand_points!r}")
        if self.min_frames < 2 or self.blend_frames < 0 or self.robust_iterations < 0:
            raise ValueError("GraspStabilizationConfig: need min_frames >= 2, blend_frames >= 0, "
                             f"robust_iterations >= 0, got {self.min_frames}, {self.blend_frames}, "
                             f"{self.robust_iterations}")


def _project_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (SVD, det +1) of (..., 3, 3) matrices."""
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[:-2] + (3,))
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def _robust_mean(R: np.ndarray, p: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """L1 (Weiszfeld) means of rotations (L, 3, 3) (chordal) and positions (L, 3): a few badly
    detected frames of a grasp do not pull the grasp transform."""
    Rm, pm = _project_rotation(R.mean(0)), np.median(p, axis=0)
    for _ in range(iterations):
        wr = 1.0 / np.maximum(np.linalg.norm((R - Rm).reshape(len(R), 9), axis=1), 1e-6)
        wp = 1.0 / np.maximum(np.linalg.norm(p - pm, axis=1), 1e-6)
        Rm = _project_rotation((wr[:, None, None] * R).sum(0) / wr.sum())
        pm = (wp[:, None] * p).sum(0) / wp.sum()
    return Rm, pm


def _hand_motion(joints: np.ndarray, ok: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion (R (L, 3, 3), t (L, 3)) of the whole hand per frame: joints_t ~ R ref + t (Kabsch,
    21 points, so far better conditioned than the fingertip pair); identity where not ok."""
    from demoforge.lib.geometry import umeyama

    L = joints.shape[0]
    R = np.tile(np.eye(3), (L, 1, 1))
    t = np.zeros((L, 3))
    if ok.any():
        _, R[ok], t[ok] = umeyama(np.broadcast_to(ref, joints[ok].shape), joints[ok], with_scale=False)
    return R, t


def stabilize_grasps(pose7: np.ndarray, g: np.ndarray, joints: np.ndarray,
                     config: GraspStabilizationConfig | None = None, **overrides) -> np.ndarray:
    """Rigid-grasp prior while the gripper is closed: pose7 (T, H, 7), g (T, H), joints (T, H, 21, 3).

    While a hand holds an object the grasp is rigid: the pinch frame is fixed relative to the hand,
    and the hand moves as one rigid body. Per closed interval (a run of g < 0.5) and hand:

    1. the hand's rigid motion per frame (R_t, t_t) is fitted by Kabsch over all 21 joints against
       the interval's mean hand shape (two passes: a frame's shape, then the mean of the aligned
       shapes), far better conditioned than the thumb-tip -> index-tip direction, which on a thin
       grasp (tips ~1 cm apart) turns by tens of degrees with a few millimetres of keypoint error;
    2. the grasp transform (the mapped pinch pose in the hand's frame, R_t^T R_pinch and
       R_t^T (p - t_t)) is averaged robustly (L1 / Weiszfeld) over the interval;
    3. the stabilised pinch pose is the hand's motion applied to that mean grasp transform. With
       mode "twist" only the twist about the approach axis is taken from it (x projected orthogonal
       to the mapped approach axis z; position and z as mapped); with "pose" the whole pose.

    Over ``blend_frames`` before each grasp and after each release the result is blended in / out
    (slerp / lerp), so the gripper turns to the stabilised twist while it closes, not after.
    Open intervals outside those blends and frames with non-finite joints are returned unchanged.
    """
    cfg = config or GraspStabilizationConfig()
    if overrides:
        cfg = replace(cfg, **overrides)
    p = np.array(pose7, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    j = np.asarray(joints, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 7 or g.shape != p.shape[:2] or j.shape != p.shape[:2] + (21, 3):
        raise ValueError(f"stabilize_grasps: need pose7 (T, H, 7), g (T, H), joints (T, H, 21, 3); got "
                         f"{p.shape}, {g.shape}, {j.shape}")
    if cfg.mode == "off":
        return p
    from demoforge.lib.geometry import quat_slerp

    T, H = p.shape[:2]
    out = p.copy()
    pts = np.asarray(PALM_JOINTS if cfg.hand_points == "palm" else np.arange(21))
    for h in range(H):
        ok_all = np.isfinite(j[:, h]).all(axis=(-1, -2)) & np.isfinite(p[:, h]).all(-1)
        for s, e in mask_to_ranges(g[:, h] < 0.5):
            ok = ok_all[s:e]
            if ok.sum() < cfg.min_frames:
                continue
            # frames touched: the interval plus the blends on either side
            a, b = max(0, s - cfg.blend_frames), min(T, e + cfg.blend_frames)
            J = j[a:b, h][:, pts]
            okw = ok_all[a:b]
            inside = np.zeros(b - a, bool)
            inside[s - a:e - a] = True
            use = okw & inside
            ref = J[np.flatnonzero(use)[use.sum() // 2]]
            for _ in range(2):  # template: one frame's shape, then the mean aligned shape
                R_h, t_h = _hand_motion(J, okw, ref)
                ref = np.einsum("lji,lkj->lki", R_h[use], J[use] - t_h[use, None, :]).mean(0)
            R_h, t_h = _hand_motion(J, okw, ref)
            Rg = quat_to_matrix(np.where(okw[:, None], p[a:b, h, 3:], [0, 0, 0, 1.0]))
            pg = p[a:b, h, :3]
            R_rel = np.einsum("lji,ljk->lik", R_h[use], Rg[use])
            p_rel = np.einsum("lji,lj->li", R_h[use], pg[use] - t_h[use])
            Rm, pm = _robust_mean(R_rel, p_rel, cfg.robust_iterations)
            R_new = R_h @ Rm
            p_new = np.einsum("lij,j->li", R_h, pm) + t_h
            if cfg.mode == "twist":
                z = Rg[..., :, 2]
                x, xn = _unit(R_new[..., :, 0] - np.sum(R_new[..., :, 0] * z, -1, keepdims=True) * z)
                R_new = np.where((xn > 1e-6)[:, None, None], np.stack([x, np.cross(z, x), z], axis=-1), Rg)
            # blend weight: 1 inside the interval, ramping to 0 over the blend frames outside it
            f = np.arange(a, b)
            n_b = cfg.blend_frames + 1.0
            w = np.clip(np.minimum((f - (s - n_b)) / n_b, ((e - 1 + n_b) - f) / n_b), 0.0, 1.0)
            w = np.where(inside, 1.0, w)
            q_old = np.where(okw[:, None], p[a:b, h, 3:], [0, 0, 0, 1.0])
            q = quat_slerp(q_old, matrix_to_quat(R_new), w)
            out[a:b, h, 3:] = np.where(okw[:, None], q, p[a:b, h, 3:])
            if cfg.mode == "pose":  # twist mode keeps the mapped positions bit for bit
                pos = (1 - w)[:, None] * pg + w[:, None] * p_new
                out[a:b, h, :3] = np.where(okw[:, None], pos, pg)
    return out


#: Default lowest pinch height (m) above the table top: the pinch point is the midpoint of the thumb
#: and index tip keypoints, which lie inside the fingertips, about a fingertip radius (8-10 mm) above
#: a surface they touch.
PINCH_MIN_HEIGHT = 0.010


def clamp_above_table(pose7: np.ndarray, min_height: float = PINCH_MIN_HEIGHT, table_z: float = 0.0) -> np.ndarray:
    """Raise pinch points below ``table_z + min_height`` to that height (world frame, z up; docs/architecture.md:
    the table top is z = 0). A human pinch cannot go below the table, but the ingest's ~9 mm
    position error puts a grasp of an object lying on the table (a whisk handle, approached from
    above) below it, and the gripper's fingers, which reach 6 mm beyond the pinch point, then push
    on the table. pose7 (..., 7); NaN rows stay NaN; only z changes, only where it was too low."""
    if not np.isfinite(min_height) or min_height < 0:
        raise ValueError(f"clamp_above_table: min_height must be a finite height >= 0 m, got {min_height}")
    p = np.array(pose7, dtype=np.float64)
    if p.shape[-1] != 7:
        raise ValueError(f"clamp_above_table: pose7 must have shape (..., 7), got {p.shape}")
    z = p[..., 2]
    p[..., 2] = np.where(z < table_z + min_height, table_z + min_height, z)  # NaN compares False: kept
    return p
