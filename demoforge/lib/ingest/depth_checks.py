"""Take-level checks that a take's depth can be trusted (issue 19, point 4). Pure numpy.

Depth that is all zero, mostly invalid, in the wrong unit (millimetres read as metres or the
reverse) or not aligned with the RGB image does not crash the ingest: every hand just lands at a
wrong distance -- a silent metre of error. :func:`check_depth` looks at three independent signals
and names the first problem it finds, with how to fix it:

1. **Frames with depth**: the fraction of frames with any valid pixel (``min_frame_fraction``).
2. **Range and table plane** (needs no hand): valid pixels closer than ``near_m`` (no RGB-D camera
   measures there: metres read as millimetres), farther than ``far_m`` (beyond any RGB-D sensor) or,
   on pixels whose ray meets the table plane (world z = 0), much farther than that plane (``beyond_table_factor``: millimetres read as
   metres, or a wrong ``T_world_camera``).
3. **Hands** (when a detector found hands): the fraction of detected hands with a valid depth reading
   at their anchors (``min_anchor_fraction``), and the depth-to-size ratio ``s = z_read /
   z_implied`` of :func:`demoforge.lib.perception.tracking.depth_size_ratio`: a median near 1000 is millimetres
   read as metres, near 0.001 the reverse; otherwise a median outside ``[1/ratio_tol, ratio_tol]``
   or too few consistent hands means the depth does not lie under the hands (misaligned streams or
   wrong intrinsics).

Depth that passes these checks can still be missing at the hands in part of the take (a hand near
the sensor, reflections, frames dropped by the depth stream). Those frames keep the hand's detected
2D position with a root depth interpolated from neighbouring frames, which is good for short gaps
only: :func:`depth_coverage` measures the share of frames and of each hand's used detections without
depth at the hand, and :func:`coverage_warning` says so above ``DepthCheckConfig.warn_missing_fraction``.

Depth is in metres, 0 or NaN invalid (docs/architecture.md, Conventions); frames are camera frames (OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from demoforge.lib.geometry import backproject

__all__ = ["DepthCheckConfig", "DepthFrameStats", "DepthReport", "DepthCoverage", "frame_depth_stats",
           "check_depth", "depth_coverage", "coverage_warning", "DEPTH_PROBLEMS"]

#: Codes of :attr:`DepthReport.problem` ('' = depth looks right).
DEPTH_PROBLEMS = ("", "empty_depth", "unit_m_read_as_mm", "unit_mm_read_as_m", "mostly_invalid_depth",
                  "misaligned_depth")

_FIX_UNIT = ("camera.json's \"depth_unit\"/\"depth_scale\" (float .npy depth is metres; integer .npy or "
             "16-bit PNG is depth_scale metres per unit, default 0.001)")


#: The default of ``DepthCheckConfig.warn_missing_fraction`` (measured: docs/results/issue-38-reliability.md).
WARN_MISSING_FRACTION = 0.15


@dataclass(frozen=True)
class DepthCheckConfig:
    #: At least this fraction of frames must have some valid depth.
    min_frame_fraction: float = 0.5
    #: At least this fraction of detected hands must have a depth reading at their anchors.
    min_anchor_fraction: float = 0.5
    #: Pixels nearer than this are not real readings (m).
    near_m: float = 0.05
    #: A pixel is "beyond the table" when deeper than this factor times its ray's table distance.
    beyond_table_factor: float = 3.0
    #: Fraction of (valid, table-facing) pixels too near / beyond the table that is a problem.
    max_bad_pixel_fraction: float = 0.5
    #: Hands' depth-to-size ratio accepted as consistent: [1/ratio_tol, ratio_tol].
    ratio_tol: float = 2.0
    #: Ratio medians beyond this factor (either way) are a unit error (x1000 or x0.001).
    unit_factor: float = 30.0
    #: At least this fraction of hands with depth must be consistent with their size.
    min_consistent_fraction: float = 0.5
    #: Hands with depth needed before the hand-based checks judge.
    min_hands: int = 5
    #: Subsampling step (pixels) of :func:`frame_depth_stats`.
    step: int = 8
    #: Warn when depth is missing at the hands in more than this share of the frames with a hand
    #: (docs/ingest.md: where the gripper error starts to grow).
    warn_missing_fraction: float = WARN_MISSING_FRACTION


@dataclass
class DepthFrameStats:
    """Per-frame statistics of the depth images (arrays of length T)."""

    valid_fraction: np.ndarray
    near_fraction: np.ndarray       # of valid pixels
    far_fraction: np.ndarray        # of valid pixels
    beyond_table_fraction: np.ndarray  # of valid pixels whose ray meets the table in front
    table_pixels: np.ndarray        # how many valid subsampled pixels face the table

    @classmethod
    def empty(cls, T: int) -> "DepthFrameStats":
        z = np.zeros(T)
        return cls(z.copy(), z.copy(), z.copy(), z.copy(), np.zeros(T, np.int64))


@dataclass
class DepthReport:
    """Result of :func:`check_depth`: ``problem`` '' when the depth looks right, else a code of
    :data:`DEPTH_PROBLEMS` and a one-line ``message`` saying what is wrong and how to fix it."""

    problem: str
    message: str
    frames_with_depth: float
    anchor_valid_fraction: float
    median_ratio: float
    consistent_fraction: float
    near_fraction: float
    beyond_table_fraction: float
    #: (T,) frames without any valid depth (flagged row by row whatever the verdict).
    frame_without_depth: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def ok(self) -> bool:
        return self.problem == ""


def frame_depth_stats(depth: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray | None = None,
                      step: int = 8, near_m: float = 0.05, far_m: float = 15.0,
                      beyond_table_factor: float = 3.0) -> DepthFrameStats:
    """Statistics of a batch of depth images (B, H, W) in metres on a ``step``-pixel grid."""
    d = np.asarray(depth, dtype=np.float64)[:, step // 2::step, step // 2::step]
    B, h, w = d.shape
    valid = np.isfinite(d) & (d > 0)
    n_valid = valid.sum(axis=(1, 2))
    vf = n_valid / max(h * w, 1)
    near = (valid & (d < near_m)).sum(axis=(1, 2)) / np.maximum(n_valid, 1)
    far = (valid & (d > far_m)).sum(axis=(1, 2)) / np.maximum(n_valid, 1)
    beyond = np.zeros(B)
    table_px = np.zeros(B, np.int64)
    if T_world_camera is not None:
        v, u = np.meshgrid(np.arange(h) * step + step // 2, np.arange(w) * step + step // 2, indexing="ij")
        ray = backproject(np.stack([u, v], -1), np.ones((h, w)), K)                 # camera, z = 1
        Tw = np.asarray(T_world_camera, dtype=np.float64)
        dir_w = ray @ Tw[:3, :3].T                                                   # per unit depth
        cz = Tw[2, 3]
        # depth at which the pixel's ray meets the table plane (world z = 0); only rays going down
        with np.errstate(divide="ignore", invalid="ignore"):
            z_table = np.where(dir_w[..., 2] < -1e-6, -cz / dir_w[..., 2], np.inf)
        faces = np.isfinite(z_table) & (z_table > 0) & (cz > 0)
        tv = valid & faces[None]
        table_px = tv.sum(axis=(1, 2))
        beyond = (tv & (d > beyond_table_factor * z_table[None])).sum(axis=(1, 2)) / np.maximum(table_px, 1)
    return DepthFrameStats(vf, near, far, beyond, table_px)


def _fmt(x: float) -> str:
    return "nan" if not np.isfinite(x) else (f"{x:.3g}")


def check_depth(stats: DepthFrameStats, hand_detected: np.ndarray | None = None,
                anchor_valid: np.ndarray | None = None, ratio: np.ndarray | None = None,
                config: DepthCheckConfig | None = None) -> DepthReport:
    """The take's depth verdict (module doc). hand_detected (T, 2) bool; anchor_valid (T, 2) bool: the
    hand had a depth reading; ratio (T, 2) depth-to-size ratio (NaN where none)."""
    cfg = config or DepthCheckConfig()
    T = len(stats.valid_fraction)
    has = stats.valid_fraction > 0
    frames_ok = float(has.mean()) if T else 0.0
    w = stats.valid_fraction[has]
    near = float(np.average(stats.near_fraction[has], weights=w)) if has.any() else 0.0
    far = float(np.average(stats.far_fraction[has], weights=w)) if has.any() else 0.0
    tw = stats.table_pixels * has
    beyond = float(np.average(stats.beyond_table_fraction, weights=tw)) if tw.sum() > 0 else 0.0
    det = np.zeros((T, 2), bool) if hand_detected is None else np.asarray(hand_detected, bool)
    av = np.zeros((T, 2), bool) if anchor_valid is None else np.asarray(anchor_valid, bool) & det
    r = np.full((T, 2), np.nan) if ratio is None else np.where(av, np.asarray(ratio, float), np.nan)
    n_det = int(det.sum())
    anchor_frac = float(av.sum() / n_det) if n_det else float("nan")
    rv = r[np.isfinite(r)]
    med = float(np.median(rv)) if rv.size else float("nan")
    cons = float(np.mean((rv >= 1 / cfg.ratio_tol) & (rv <= cfg.ratio_tol))) if rv.size else float("nan")
    rep = dict(frames_with_depth=frames_ok, anchor_valid_fraction=anchor_frac, median_ratio=med,
               consistent_fraction=cons, near_fraction=near, beyond_table_fraction=beyond,
               frame_without_depth=~has)
    fix = "; or pass --accept-bad-depth to ingest anyway with every affected row flagged"
    enough_hands = rv.size >= cfg.min_hands
    if frames_ok < cfg.min_frame_fraction:
        return DepthReport("empty_depth", (
            f"depth is empty (all 0 / NaN) in {int((~has).sum())} of {T} frames: check the take's depth/ "
            f"files (a missing, all-zero or misnamed depth stream){fix}"), **rep)
    far_or_beyond = max(far, beyond)
    if (enough_hands and med > cfg.unit_factor) or (not enough_hands and far_or_beyond > cfg.max_bad_pixel_fraction):
        what = (f"hands read at {_fmt(med)} x the depth their size implies" if enough_hands else
                f"{100 * far_or_beyond:.0f} % of the valid pixels lie beyond the sensor's range or far "
                "below the table plane")
        return DepthReport("unit_mm_read_as_m", (
            f"depth looks like millimetres read as metres ({what}): fix {_FIX_UNIT}{fix}"), **rep)
    if (enough_hands and med < 1 / cfg.unit_factor) or (not enough_hands and near > cfg.max_bad_pixel_fraction):
        what = (f"hands read at {_fmt(med)} x the depth their size implies" if enough_hands else
                f"{100 * near:.0f} % of the valid pixels are nearer than {100 * cfg.near_m:.0f} cm")
        return DepthReport("unit_m_read_as_mm", (
            f"depth looks like metres read as millimetres ({what}): fix {_FIX_UNIT}{fix}"), **rep)
    if n_det >= cfg.min_hands and anchor_frac < cfg.min_anchor_fraction:
        return DepthReport("mostly_invalid_depth", (
            f"only {100 * anchor_frac:.0f} % of the detected hands have valid depth under them (need "
            f"{100 * cfg.min_anchor_fraction:.0f} %): the depth is mostly 0 / NaN where the hands are "
            f"(sensor range, or depth not aligned to the RGB){fix}"), **rep)
    if enough_hands and (not (1 / cfg.ratio_tol <= med <= cfg.ratio_tol) or cons < cfg.min_consistent_fraction):
        return DepthReport("misaligned_depth", (
            f"the depth under the hands does not match their size (median depth/size ratio {_fmt(med)}, "
            f"{100 * cons:.0f} % of hands consistent): align the depth to the RGB camera and check K in "
            f"camera.json and the depth unit{fix}"), **rep)
    return DepthReport("", "", **rep)


@dataclass(frozen=True)
class DepthCoverage:
    """How much of a take has depth at its hands: ``hand_missing`` (2,) the share of each hand's used
    detections without a depth reading at its anchors (NaN: no detection); ``frame_missing`` the share
    of frames with a used detection where some detected hand has none (NaN: no such frame)."""

    hand_missing: np.ndarray
    frame_missing: float
    frames_with_hands: int


def depth_coverage(detected: np.ndarray, no_depth: np.ndarray) -> DepthCoverage:
    """detected (T, 2): the hand's detection is used in the frame; no_depth (T, 2): it had no depth
    reading at its anchors (aligned_keypoints' ``detected`` and ``no_depth``)."""
    det = np.asarray(detected, bool)
    missing = np.asarray(no_depth, bool) & det
    n_det = det.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        hand = np.where(n_det > 0, missing.sum(axis=0) / n_det, np.nan)
    frames = det.any(axis=1)
    n = int(frames.sum())
    return DepthCoverage(hand, float(missing.any(axis=1).sum() / n) if n else float("nan"), n)


def coverage_warning(take: str, coverage: DepthCoverage, config: DepthCheckConfig | None = None) -> str:
    """One line when depth is missing at the hands in more frames than the configured share, else ''."""
    cfg = config or DepthCheckConfig()
    if not coverage.frame_missing > cfg.warn_missing_fraction:
        return ""
    hands = ", ".join(f"{side} {100 * f:.0f} %" for side, f in zip(("left", "right"), coverage.hand_missing)
                      if np.isfinite(f))
    return (f"take {take}: depth is missing at the hands in {100 * coverage.frame_missing:.0f} % of the frames "
            f"with a hand ({hands} of each hand's detections), over the {100 * cfg.warn_missing_fraction:.0f} % "
            "beyond which the gripper error grows (docs/ingest.md): those frames get a depth interpolated from "
            "their neighbours. Check the depth stream (range, reflective surfaces, dropped frames)")
