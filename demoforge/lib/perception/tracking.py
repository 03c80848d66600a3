"""Temporal hand tracker over any detector's per-frame detections (issue 19, point 3).

A per-frame detector (the thesis's rule: best left and best right candidate per frame) answers each
frame on its own: it mislabels hands, sees a hand twice, and "finds" hands in the background. Filling
the gaps between such detections invents trajectories. This module decides, per take and per hand
slot (0 = left, 1 = right; docs/architecture.md, Conventions), which detections belong to a hand track:

1. **Depth consistency** (when depth at the hand is given): a detected hand must lie on depth pixels
   at a distance consistent with its apparent size. The ratio ``s = z_read / z_implied``
   (``z_implied = f * spread_xy / spread_px``: the depth at which the detector's metric hand, its own
   size estimate, has the 2D spread of its keypoints under weak perspective) is about 1 for a real hand, far from 1 for a "hand" on the background
   or for depth in the wrong unit. Detections with ``s`` outside ``[1/depth_ratio_tol,
   depth_ratio_tol]`` are rejected (no reading: not judged).
2. **Duplicates**: both labels on the same physical hand (mean 2D joint distance under
   ``duplicate_sizes`` hand sizes): the less confident one is dropped.
3. **Identity**: left/right swaps and handedness flips are repaired from 2D continuity
   (:func:`demoforge.lib.perception.track_repair.repair_swaps`: each detection goes to the physical hand whose last
   position is closer; positions older than ``max_gap_frames`` are forgotten, so sparse
   detections are not re-labelled against where a hand was seconds ago).
4. **One hand, two labels**: a per-frame detector's handedness flips on one hand in bursts (often
   when it finds the hand again after losing it), and each burst could be born as a track of its
   own: a second "trusted" hand beside the real one. When the two labels' sustained detections (those
   that would form tracks) never appear in the same frame, and every change of label happens at the
   same place (within ``one_hand_same_place_sizes + one_hand_sizes_per_frame * frames apart`` hand
   sizes of the last detection, the frames counted up to ``max_gap_frames``), they are one hand, and
   its detections go to the label the detector gave most of them (:func:`one_hand_relabel`). Two
   hands seen together in one frame keep both labels, and so do labels that change to another place
   (a detector that sees the two hands of a take one at a time).
5. **Births**: per hand, the accepted detections are cut into segments at gaps longer than
   ``max_gap_frames`` and at jumps no hand can make (centroid moved more than
   ``max_jump_sizes + max_jump_sizes_per_frame * frames`` hand sizes). A segment becomes a track only
   if it holds ``birth_k`` detections within ``birth_window`` consecutive frames (sustained evidence)
   and at least ``min_track_detections`` in all; detections in other segments are rejected as
   isolated. A hand that is absent from the take therefore stays absent.
6. **Trust**: :func:`hand_trust` says whether a hand's trajectory covers enough of the take to
   build episodes from (``min_trusted_fraction`` of the frames and ``min_trusted_frames``).

Gap filling itself stays in demoforge.lib.ingest.alignment (bounded by ``max_gap_frames`` through
``AlignmentConfig.max_gap_frames``; every filled frame is flagged there). Everything here is
vectorised over the take except the identity repair's scalar loop (microseconds per frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.perception.robust import nan_median
from demoforge.lib.perception.track_repair import repair_swaps


__all__ = ["TrackerConfig", "TrackResult", "REJECT_REASONS", "depth_size_ratio", "hand_size_px",
           "track_hands", "one_hand_relabel", "bounded_fill_mask", "hand_trust"]

#: Codes of ``TrackResult.rejected``: why a detection was not used.
REJECT_REASONS = ("", "depth_inconsistent", "duplicate", "isolated")


@dataclass(frozen=True)
class TrackerConfig:
    """Parameters of :func:`track_hands` and :func:`hand_trust` (frames at the take's fps)."""

    #: A track is born on ``birth_k`` detections within ``birth_window`` consecutive frames.
    birth_k: int = 3
    birth_window: int = 5
    #: A track must hold at least this many detections in all.
    min_track_detections: int = 5
    #: Longest run of frames without a detection inside a track (longer ends the track); also the
    #: longest gap the alignment may fill.
    max_gap_frames: int = 15
    #: Largest plausible centroid jump between consecutive detections, in hand sizes (bounding-box
    #: diagonal): ``max_jump_sizes + max_jump_sizes_per_frame * frames apart``.
    max_jump_sizes: float = 1.5
    max_jump_sizes_per_frame: float = 1.0
    #: Two labels closer than this (mean 2D joint distance, hand sizes) are the same hand.
    duplicate_sizes: float = 0.2
    #: A detection whose depth-to-size ratio is outside [1/tol, tol] does not lie on its depth.
    depth_ratio_tol: float = 2.0
    #: Repair left/right swaps and handedness flips from 2D continuity.
    repair_identity: bool = True
    swap_margin_px: float = 10.0
    #: Two labels never seen in one frame are one hand when each label change stays within
    #: ``one_hand_same_place_sizes + one_hand_sizes_per_frame * frames apart`` hand sizes (module doc,
    #: step 4; frames counted up to max_gap_frames: at most 1.25 sizes; 0.05 size a frame is about
    #: 1 cm at 30 fps). 0 turns the rule off.
    one_hand_same_place_sizes: float = 0.5
    one_hand_sizes_per_frame: float = 0.05
    #: A hand is trusted when its trajectory covers this fraction of the take and this many frames.
    min_trusted_fraction: float = 0.25
    min_trusted_frames: int = 10

    def __post_init__(self) -> None:
        if not 1 <= self.birth_k <= self.birth_window:
            raise ValueError(f"need 1 <= birth_k <= birth_window, got {self.birth_k}, {self.birth_window}")
        if self.min_track_detections < self.birth_k:
            raise ValueError("min_track_detections must be >= birth_k")
        if self.max_gap_frames < 0:
            raise ValueError(f"max_gap_frames must be >= 0, got {self.max_gap_frames}")
        if not self.depth_ratio_tol > 1:
            raise ValueError(f"depth_ratio_tol must be > 1, got {self.depth_ratio_tol}")
        if not self.one_hand_same_place_sizes >= 0:
            raise ValueError(f"one_hand_same_place_sizes must be >= 0, got {self.one_hand_same_place_sizes}")


@dataclass
class TrackResult:
    """Output of :func:`track_hands`; slots are physical hands (0 = left, 1 = right) after identity."""

    #: (T,) the input's two slots were exchanged in this frame (swap or handedness flip repaired).
    swapped: np.ndarray
    #: (T, 2) input slot each output slot's detection comes from (-1: none).
    source_slot: np.ndarray
    #: (T, 2) a detection sits in this slot after identity repair (before acceptance).
    detected: np.ndarray
    #: (T, 2) the detection belongs to a confirmed track (the only ones later stages may use).
    accepted: np.ndarray
    #: (T, 2) int8 index into :data:`REJECT_REASONS` (0 = not rejected).
    rejected: np.ndarray
    #: (T, 2) track number per hand (0, 1, ...) on every frame of a track's span, -1 elsewhere.
    track_id: np.ndarray
    #: (T, 2) depth-to-size ratio s of the detection (NaN: no depth reading or no detection).
    depth_ratio: np.ndarray

    @property
    def n_tracks(self) -> np.ndarray:
        return self.track_id.max(axis=0) + 1

    def reason(self) -> np.ndarray:
        """(T, 2) the rejection reason as text ('' when not rejected)."""
        return np.asarray(REJECT_REASONS, dtype=object)[self.rejected]


def hand_size_px(joints_px: np.ndarray) -> np.ndarray:
    """(..., 21, 2) -> (...) bounding-box diagonal of the 2D joints, px (NaN if any is NaN)."""
    p = np.asarray(joints_px, dtype=np.float64)
    return np.linalg.norm(p.max(axis=-2) - p.min(axis=-2), axis=-1)


def _spread(p: np.ndarray) -> np.ndarray:
    """RMS distance of points (..., N, D) to their centroid."""
    return np.sqrt(np.mean(np.sum((p - p.mean(axis=-2, keepdims=True)) ** 2, -1), -1))


def depth_size_ratio(joints_cam: np.ndarray, joints_px: np.ndarray, anchor_depth: np.ndarray,
                     K: np.ndarray) -> np.ndarray:
    """s = z_read / z_implied per detection (see the module doc); NaN where no depth or no hand.

    joints_cam (..., 21, 3) the detector's camera-frame joints (only their root-relative shape is
    used: metric, the detector's own size estimate); joints_px (..., 21, 2); anchor_depth (..., A)
    robust depth readings at the hand's anchors (m, NaN invalid); K (3, 3).
    """
    X = np.asarray(joints_cam, dtype=np.float64)
    P = np.asarray(joints_px, dtype=np.float64)
    z, _ = nan_median(np.where(np.isfinite(anchor_depth), anchor_depth, np.nan), axis=-1)
    f = 0.5 * (float(K[0, 0]) + float(K[1, 1]))
    with np.errstate(all="ignore"):
        # weak perspective: the detector's hand, seen across the viewing direction, spans
        # f * spread_xy / z pixels at depth z (no singularity for absurd depths, e.g. 0.6 mm)
        z_implied = f * _spread((X - X[..., :1, :])[..., :2]) / _spread(P)
        ratio = z / z_implied
    return np.where(np.isfinite(ratio) & (ratio > 0), ratio, np.nan)


def _confirm(evidence: np.ndarray, cen: np.ndarray, size: np.ndarray, cfg: TrackerConfig
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per hand: (accepted (T, 2), track_id (T, 2)) from evidence frames (see module doc, step 4)."""
    T = evidence.shape[0]
    accepted = np.zeros((T, 2), bool)
    track_id = np.full((T, 2), -1, np.int64)
    for h in range(2):
        idx = np.flatnonzero(evidence[:, h])
        n = idx.size
        if n == 0:
            continue
        gaps = np.diff(idx)
        jump = np.linalg.norm(cen[idx[1:], h] - cen[idx[:-1], h], axis=-1)
        scale = np.fmax(size[idx[1:], h], size[idx[:-1], h])
        allowed = scale * (cfg.max_jump_sizes + cfg.max_jump_sizes_per_frame * gaps)
        brk = (gaps - 1 > cfg.max_gap_frames) | ~(jump <= allowed)
        seg = np.concatenate([[0], np.cumsum(brk)])
        k = cfg.birth_k
        birth = np.zeros(n, bool)
        if n >= k:
            birth[: n - k + 1] = (idx[k - 1:] - idx[: n - k + 1] < cfg.birth_window) & (seg[k - 1:] == seg[: n - k + 1])
        n_seg = int(seg[-1]) + 1
        ok_seg = (np.bincount(seg, weights=birth, minlength=n_seg) > 0) & \
                 (np.bincount(seg, minlength=n_seg) >= cfg.min_track_detections)
        keep = ok_seg[seg]
        accepted[idx[keep], h] = True
        # number the kept segments 0, 1, ... and mark each one's span (first..last detection)
        kept = np.flatnonzero(ok_seg)
        if kept.size:
            first = np.array([idx[seg == s][0] for s in kept])
            last = np.array([idx[seg == s][-1] for s in kept])
            d = np.zeros(T + 1, np.int64)
            np.add.at(d, first, np.arange(kept.size) + 1)
            np.add.at(d, last + 1, -(np.arange(kept.size) + 1))
            track_id[:, h] = np.cumsum(d)[:T] - 1
    return accepted, track_id


def one_hand_relabel(evidence: np.ndarray, cen: np.ndarray, size: np.ndarray, cfg: TrackerConfig,
                     source: np.ndarray | None = None) -> np.ndarray:
    """(T,) frames whose detection is moved to the other label: one hand seen under two labels
    (module doc, step 4). ``evidence`` (T, 2) detections after identity repair; ``cen`` (T, 2, 2) their
    2D centroids, ``size`` (T, 2) their sizes (px); ``source`` (T, 2) the detector's label of each
    (default: the slot itself), whose majority names the hand."""
    T = evidence.shape[0]
    move = np.zeros(T, bool)
    if cfg.one_hand_same_place_sizes <= 0:
        return move
    sustained, _ = _confirm(evidence, cen, size, cfg)
    if (sustained.all(axis=1)).any() or not sustained.any(axis=0).all():
        return move  # seen together once (two hands), or one label only (nothing to merge)
    t = np.flatnonzero(sustained.any(axis=1))                    # frames with one sustained detection
    slot = sustained[t, 1].astype(np.int64)
    label = slot if source is None else source[t, slot]
    c, s = cen[t, slot], size[t, slot]
    change = np.flatnonzero(slot[1:] != slot[:-1])              # label changes between t[i] and t[i + 1]
    apart = np.minimum(t[change + 1] - t[change], cfg.max_gap_frames)
    reach = (cfg.one_hand_same_place_sizes + cfg.one_hand_sizes_per_frame * apart) * np.fmax(s[change + 1], s[change])
    joined = np.zeros(t.size - 1, bool)
    joined[change] = np.linalg.norm(c[change + 1] - c[change], axis=-1) <= reach
    # a hand: a run of sustained detections whose label changes all stay at its place
    same = (slot[1:] == slot[:-1]) | joined
    hand = np.concatenate([[0], np.cumsum(~same)])
    for h in np.unique(hand):
        members = hand == h
        if np.unique(slot[members]).size < 2:
            continue
        named = int(np.argmax(np.bincount(label[members], minlength=2)))  # on a tie: left
        move[t[members & (slot != named)]] = True
    return move


def track_hands(joints_px: np.ndarray, present: np.ndarray, confidence: np.ndarray | None = None, *,
                joints_cam: np.ndarray | None = None, anchor_depth: np.ndarray | None = None,
                K: np.ndarray | None = None, config: TrackerConfig | None = None,
                use_depth: bool = True) -> TrackResult:
    """Decide which per-frame detections form hand tracks (module doc, steps 1-4).

    joints_px (T, 2, 21, 2) the detector's 2D keypoints, slot 0 = labelled left; present (T, 2);
    confidence (T, 2) (ties of duplicates); joints_cam (T, 2, 21, 3), anchor_depth (T, 2, A) and K
    enable the depth check (``use_depth=False`` skips it, e.g. for depth the user accepted as bad).
    """
    cfg = config or TrackerConfig()
    P = np.asarray(joints_px, dtype=np.float64)
    if P.ndim != 4 or P.shape[1:] != (2, 21, 2):
        raise ValueError(f"joints_px must be (T, 2, 21, 2), got {P.shape}")
    T = P.shape[0]
    det = np.asarray(present, bool) & np.isfinite(P).all(axis=(2, 3))
    conf = np.zeros((T, 2)) if confidence is None else np.nan_to_num(np.asarray(confidence, float))
    rejected = np.zeros((T, 2), np.int8)

    ratio = np.full((T, 2), np.nan)
    if use_depth and joints_cam is not None and anchor_depth is not None and K is not None:
        ratio = np.where(det, depth_size_ratio(joints_cam, P, anchor_depth, K), np.nan)
        bad = det & np.isfinite(ratio) & ((ratio > cfg.depth_ratio_tol) | (ratio < 1.0 / cfg.depth_ratio_tol))
        rejected[bad] = REJECT_REASONS.index("depth_inconsistent")
        det = det & ~bad

    size = hand_size_px(P)
    both = det.all(axis=1)
    with np.errstate(invalid="ignore"):
        mean_d = np.mean(np.linalg.norm(P[:, 0] - P[:, 1], axis=-1), axis=-1)
        dup = both & (mean_d < cfg.duplicate_sizes * np.fmax(size[:, 0], size[:, 1]))
    drop = np.where(conf[:, 0] >= conf[:, 1], 1, 0)               # the less confident label goes
    dup_mask = dup[:, None] & (np.arange(2)[None, :] == drop[:, None])
    rejected[dup_mask] = REJECT_REASONS.index("duplicate")
    det = det & ~dup_mask

    cen = np.where(det[..., None], np.nanmean(np.where(det[..., None, None], P, 0.0), axis=2), np.nan)
    if cfg.repair_identity:
        swapped = repair_swaps(cen, det, cfg.swap_margin_px, max_age=cfg.max_gap_frames)
    else:
        swapped = np.zeros(T, bool)
    src = np.where(swapped[:, None], np.array([1, 0]), np.array([0, 1]))
    tt = np.arange(T)[:, None]
    det, cen, size, rejected, ratio = det[tt, src], cen[tt, src], size[tt, src], rejected[tt, src], ratio[tt, src]
    move = one_hand_relabel(det, cen, size, cfg, source=src)
    if move.any():
        swapped = swapped ^ move
        flip = np.where(move[:, None], np.array([1, 0]), np.array([0, 1]))
        src = src[tt, flip]
        det, cen, size, rejected, ratio = det[tt, flip], cen[tt, flip], size[tt, flip], rejected[tt, flip], ratio[tt, flip]

    accepted, track_id = _confirm(det, cen, size, cfg)
    rejected = np.where(det & ~accepted, np.int8(REJECT_REASONS.index("isolated")), rejected)
    return TrackResult(swapped=swapped, source_slot=np.where(det, src, -1), detected=det,
                       accepted=accepted, rejected=rejected.astype(np.int8), track_id=track_id,
                       depth_ratio=ratio)


def bounded_fill_mask(good: np.ndarray, max_gap: int | None) -> np.ndarray:
    """(T, 2) frames that may hold filled values: good frames, gaps of at most ``max_gap`` frames
    between good frames, and at most ``max_gap`` frames before the first / after the last one.
    ``max_gap`` None: everything (the unbounded fill)."""
    good = np.asarray(good, bool)
    T = good.shape[0]
    if max_gap is None:
        return np.ones_like(good)
    t = np.arange(T)[:, None]
    prev = np.maximum.accumulate(np.where(good, t, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(good, t, T)[::-1], axis=0)[::-1]
    has_p, has_n = prev >= 0, nxt < T
    interior = has_p & has_n & (nxt - prev - 1 <= max_gap)
    head = ~has_p & has_n & (nxt - t <= max_gap)
    tail = has_p & ~has_n & (t - prev <= max_gap)
    return good | interior | head | tail


def hand_trust(tracked: np.ndarray, detected: np.ndarray, accepted: np.ndarray,
               config: TrackerConfig | None = None) -> tuple[np.ndarray, list[str]]:
    """Per hand: (trusted (2,) bool, reason per hand: '' when trusted, else why, in words).

    tracked (T, 2): the hand's trajectory holds a value (accepted or filled); detected (T, 2): a
    detection was made (after identity); accepted (T, 2): it belonged to a track.
    """
    cfg = config or TrackerConfig()
    T = max(int(np.asarray(tracked).shape[0]), 1)
    n_tr = np.asarray(tracked, bool).sum(0)
    n_det = np.asarray(detected, bool).sum(0)
    n_acc = np.asarray(accepted, bool).sum(0)
    # a take shorter than the frame minimum is judged by its fraction alone (an 8-frame clip tracked
    # throughout is as trustworthy as it can be)
    need = max(min(cfg.min_trusted_frames, T), cfg.min_trusted_fraction * T)
    trusted = n_tr >= need
    reasons = []
    for h in range(2):
        if trusted[h]:
            reasons.append("")
        elif n_det[h] == 0:
            reasons.append("never detected")
        elif n_acc[h] == 0:
            reasons.append(f"only isolated detections ({int(n_det[h])} of {T} frames), no sustained track")
        else:
            reasons.append(f"tracked in {int(n_tr[h])} of {T} frames ({100 * n_tr[h] / T:.0f} %), under the "
                           f"{int(np.ceil(need))} frames needed ({100 * cfg.min_trusted_fraction:.0f} % of the take, "
                           f"at least {min(cfg.min_trusted_frames, T)})")
    return trusted, reasons
