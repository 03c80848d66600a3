"""Simulated HaMeR-like hand detector: ground-truth joints in, realistic predictions out.

OUTPUTS OF THIS MODULE ARE SIMULATED. They are not the output of any neural network. Every table,
plot and report row built from them must carry ``detector = "simulated"`` (the value of
:data:`DETECTOR_NAME`, also stored in :attr:`SimulatedDetections.detector`), so that they are never
mistaken for, or averaged with, results of a real detector (HaMeR, WiLoR, MediaPipe, ...).

Purpose
-------
demoforge renders synthetic RGB-D demonstrations whose hand joints are known exactly. This module
turns that ground truth into predictions with the failure modes the thesis reports for HaMeR
(sections 3.1 and 5.1), so that the downstream stages -- depth alignment, outlier freeze,
left/right swap repair, gripper mapping -- can be measured against known truth.

Error model
-----------
Input: ground-truth camera-frame joints ``X[t, h, j]`` (OpenCV camera frame, metres; hand 0 = left,
1 = right; 21 joints in MediaPipe order, joint 0 = wrist = root ``r``). Each physical hand ``h``
gets its own independent errors (HaMeR runs once per hand crop). Per frame ``t`` and hand:

1. Hand-local joint noise ``n[t, h, j]``: zero-mean Gaussian, added to the wrist-relative hand
   shape ``X - r`` (after the rotation jitter of step 2, before the scale and depth errors of
   steps 3-4, so it moves and scales with the hand). It is accumulated along the kinematic tree
   (each joint's noise is its parent's noise plus an independent increment), so neighbouring
   joints move together, bone lengths stay plausible and fingertips are noisier than knuckles,
   as in real regressors. The
   increment sigma is set so that the RMS per-axis sigma over the 21 joints equals
   ``joint_noise_std_m`` (about 2.7 mm at the wrist, 6.1 mm at the tips for the 5 mm default).
   Independent from frame to frame (HaMeR infers every frame on its own).
2. Rotation jitter ``R[t, h]`` of the whole hand about its wrist: axis-angle vector with i.i.d.
   Gaussian components, RMS angle ``rotation_jitter_deg``. Shape after steps 1-2:
   ``S = R (X - r) + n`` (so ``r + S`` is the "2D-accurate" hand at the true position).
3. Scale error ``c[t, h] = exp(b_c + e_c)``: a per-take bias ``b_c ~ N(0, scale_error_log_std)``
   plus per-frame jitter ``e_c ~ N(0, scale_jitter_log_std)``; the predicted hand is ``c`` times
   too large (MANO shape / hand size mis-estimated).
4. Global depth error (the dominant error). HaMeR regresses a weak-perspective camera for a
   virtual focal length; converting it to a translation for the true intrinsics places the hand
   at a wrong depth along the viewing ray through its root, while its 2D position stays right.
   With a weak-perspective camera the implied depth is proportional to the assumed hand size, so
   the root is scaled along its ray by ``s[t, h] = g[t, h] * c[t, h]`` where the focal-mismatch
   factor is ``log g = log(depth_ratio) + b_g + w[t] + e_g[t]``: a per-take bias
   ``b_g ~ N(0, depth_bias_log_std)``, a slow mean-reverting random walk ``w`` (stationary
   Ornstein-Uhlenbeck / AR(1) process, std ``depth_walk_log_std``, time constant
   ``depth_walk_tau_s``) and per-frame jitter ``e_g ~ N(0, depth_jitter_log_std)``. Prediction:

       joints_cam = s * r + c * S

   The root's 2D projection is unchanged (it moves along its own ray); the other joints project
   closer to the root by a factor ``c / s`` (a metric-size hand placed too far away), exactly
   what projecting HaMeR's raw 3D output with the true K shows. Depth look-ups (thesis 3.1.2)
   should therefore sample the depth map at ``joints_px``, not at the projection of
   ``joints_cam``, except at the root where the two agree up to the noise. With the default
   ``depth_ratio = 2.9`` and hands 0.5-0.8 m from the camera the raw MPJPE is about 1.3 m
   (measured: 1.32 m mean over 100 takes of 300 frames, 1.03-1.70 m 5th-95th percentile per
   take; the thesis measured 1.30 / 1.31 m left / right on ARCTIC, Table 1); translating each
   predicted hand so that its wrist matches ground truth leaves about 1.2 cm (0.8-2.2 cm per
   take; the thesis after its depth-anchor translation: 2.3-2.4 cm), i.e. the error is almost
   entirely a translation along the ray.
5. 2D keypoints. The real HaMeR's 2D keypoints are far better than its 3D depth, so
   ``joints_px = project(K, r + S) + p`` with i.i.d. pixel noise ``p ~ N(0, pixel_noise_px)`` per
   coordinate: the noisy, jittered hand at its TRUE position, projected with the true K (no
   depth or scale error). At f = 615 px and 0.5-0.8 m the 2D MPJPE is about 7 px (measured
   6.4-8.7 px per take; the thesis's 25-26 px on ARCTIC was at f ~ 2430 px, i.e. about 6.5 px
   at f = 615 px: the same angular error).
6. Left/right swaps. Swap events start as a renewal process at ``swap_rate_hz`` events per second
   of video (gap between events geometric, duration uniform on ``swap_duration_frames``,
   inclusive). On a swapped frame the slot labelled left holds the right hand's complete
   prediction (3D, 2D, confidence, presence) and vice versa. Swaps are only injected on frames
   where both hands exist in the ground truth; ``injected_swap[t]`` marks them.
7. Missed detections. Per physical hand, independent runs of missed frames start at
   ``miss_rate_hz`` runs per second with lengths uniform on ``miss_duration_frames``. A missed
   hand has NaN joints, ``present = False``, ``missed = True``, confidence 0.
8. Confidence in [0, 1]: ``conf_base + N(0, conf_noise_std)``, minus ``swap_conf_drop`` on
   swapped frames, minus ``near_miss_conf_drop * (1 - d / (near_miss_frames + 1))`` on frames
   ``d <= near_miss_frames`` frames away from a missed frame of the same hand, clipped to
   [0, 1]. Absent detections have confidence 0.

A hand that is absent from the ground truth (all of its 63 coordinates NaN) stays absent:
NaN joints, ``present = False``, ``missed = False``, confidence 0. Output arrays are indexed by
output slot (0 = labelled left, 1 = labelled right), i.e. after the swap.

Randomness: one seed drives independent sub-streams (``numpy.random.SeedSequence.spawn``) for
each error source, so changing e.g. the swap rate does not change the joint noise of the same
seed; this lets a test compare a take with and without swaps. With
:meth:`SimulatedDetectorConfig.zero_noise` the prediction equals the ground truth exactly and
``joints_px`` equals :func:`project_points` of the ground truth exactly.

Where the thesis's numbers come from: the 1.3 m / 2 cm MPJPE (before / after depth alignment)
and the 25 px 2D MPJPE are its ARCTIC results (section 5.1.1, Tables 1-2); on its self-recorded
takes it reports no metrics (no ground truth), only failure cases such as left/right swaps.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter

__all__ = [
    "DETECTOR_NAME",
    "N_JOINTS",
    "PARENTS",
    "SimulatedDetectorConfig",
    "SimulatedDetections",
    "project_points",
    "simulate_detections",
]

#: Label that every table row produced from these outputs must carry in its ``detector`` column.
DETECTOR_NAME = "simulated"

from demoforge.lib.geometry import project_points  # noqa: E402,F401  (re-exported)
from demoforge.lib.joints import N_JOINTS, PARENTS  # noqa: E402  (re-exported)


def _ancestor_matrix() -> np.ndarray:
    """A[j, k] = 1 where k is j itself or one of its ancestors (wrist included)."""
    a = np.zeros((N_JOINTS, N_JOINTS))
    for j in range(N_JOINTS):
        k = j
        while k >= 0:
            a[j, k] = 1.0
            k = PARENTS[k]
    return a


_ANCESTORS = _ancestor_matrix()
# Chain noise of joint j has per-axis variance sigma_inc^2 * (number of ancestors incl. itself);
# normalise so that the RMS per-axis sigma over the 21 joints equals the configured sigma.
_CHAIN_NORM = float(np.sqrt(_ANCESTORS.sum(axis=1).mean()))


@dataclass(frozen=True)
class SimulatedDetectorConfig:
    """Parameters of the simulated detector's error model (see the module docstring).

    Every default is chosen to reproduce the thesis's HaMeR statistics on hands 0.5-0.8 m in
    front of a camera with f ~ 600 px. All standard deviations are >= 0; zero switches a source off.
    """

    #: RMS over the 21 joints of the per-axis sigma (m) of the hand-local joint noise,
    #: accumulated along the kinematic tree (wrist ~0.54x, fingertips ~1.22x this value).
    joint_noise_std_m: float = 0.005
    #: RMS angle (degrees) of the per-frame rotation jitter of the whole hand about its wrist.
    rotation_jitter_deg: float = 3.0
    #: Median factor by which the root's camera-frame position is scaled along its viewing ray
    #: (focal-length mismatch of the weak-perspective camera). 1 = no depth error. 2.9 gives
    #: about 1.3 m raw MPJPE for hands 0.5-0.8 m from the camera.
    depth_ratio: float = 2.9
    #: Std of the per-take, per-hand bias of log(depth factor).
    depth_bias_log_std: float = 0.10
    #: Stationary std of the slow random walk (Ornstein-Uhlenbeck) of log(depth factor).
    depth_walk_log_std: float = 0.08
    #: Time constant (s) of that random walk: its autocorrelation after tau seconds is 1/e.
    depth_walk_tau_s: float = 2.0
    #: Std of the independent per-frame jitter of log(depth factor).
    depth_jitter_log_std: float = 0.02
    #: Std of the per-take, per-hand bias of log(hand scale); the depth factor includes the same
    #: scale (a bigger predicted hand is placed proportionally farther away).
    scale_error_log_std: float = 0.08
    #: Std of the per-frame jitter of log(hand scale).
    scale_jitter_log_std: float = 0.01
    #: Std (px) of i.i.d. Gaussian noise added to each 2D keypoint coordinate.
    pixel_noise_px: float = 1.0
    #: Left/right swap events per second of video (0 = none).
    swap_rate_hz: float = 0.1
    #: Inclusive (min, max) length of a swap event, in frames.
    swap_duration_frames: tuple[int, int] = (2, 6)
    #: Missed-detection runs per second of video, per hand (0 = none).
    miss_rate_hz: float = 0.2
    #: Inclusive (min, max) length of a run of missed frames.
    miss_duration_frames: tuple[int, int] = (1, 4)
    #: Mean confidence of an ordinary detection.
    conf_base: float = 0.92
    #: Std of the per-frame Gaussian noise on the confidence.
    conf_noise_std: float = 0.03
    #: Confidence subtracted on swapped frames.
    swap_conf_drop: float = 0.35
    #: Confidence subtracted next to a miss (linearly fading over ``near_miss_frames``).
    near_miss_conf_drop: float = 0.30
    #: How many frames before/after a missed run have lowered confidence.
    near_miss_frames: int = 3
    #: Frame rate (Hz) used to turn the per-second rates and time constants into frames.
    fps: float = 30.0
    #: Seed of the random generator (overridden by the ``seed`` argument of
    #: :func:`simulate_detections` when that is given).
    seed: int = 0

    def __post_init__(self) -> None:
        nonneg = (
            "joint_noise_std_m", "rotation_jitter_deg", "depth_bias_log_std",
            "depth_walk_log_std", "depth_jitter_log_std", "scale_error_log_std",
            "scale_jitter_log_std", "pixel_noise_px", "swap_rate_hz", "miss_rate_hz",
            "conf_noise_std", "swap_conf_drop", "near_miss_conf_drop",
        )
        for name in nonneg:
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"SimulatedDetectorConfig.{name} must be finite and >= 0, got {v!r}")
        for name in ("depth_ratio", "depth_walk_tau_s", "fps"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"SimulatedDetectorConfig.{name} must be finite and > 0, got {v!r}")
        if not 0.0 <= self.conf_base <= 1.0:
            raise ValueError(f"SimulatedDetectorConfig.conf_base must be in [0, 1], got {self.conf_base!r}")
        if int(self.near_miss_frames) != self.near_miss_frames or self.near_miss_frames < 0:
            raise ValueError(
                f"SimulatedDetectorConfig.near_miss_frames must be an integer >= 0, got {self.near_miss_frames!r}")
        for name in ("swap_duration_frames", "miss_duration_frames"):
            v = getattr(self, name)
            if (len(v) != 2 or any(int(x) != x for x in v) or v[0] < 1 or v[1] < v[0]):
                raise ValueError(
                    f"SimulatedDetectorConfig.{name} must be integers (min, max) with 1 <= min <= max, got {v!r}")

    @classmethod
    def zero_noise(cls, **overrides) -> "SimulatedDetectorConfig":
        """A config with every error source off: predictions equal the ground truth exactly."""
        base = dict(
            joint_noise_std_m=0.0, rotation_jitter_deg=0.0, depth_ratio=1.0,
            depth_bias_log_std=0.0, depth_walk_log_std=0.0, depth_jitter_log_std=0.0,
            scale_error_log_std=0.0, scale_jitter_log_std=0.0, pixel_noise_px=0.0,
            swap_rate_hz=0.0, miss_rate_hz=0.0, conf_noise_std=0.0,
        )
        base.update(overrides)
        return cls(**base)

    def with_(self, **changes) -> "SimulatedDetectorConfig":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


@dataclass(frozen=True)
class SimulatedDetections:
    """Simulated detections of one take. Slot 0 = labelled left, 1 = labelled right.

    Label every table row derived from these with ``detector = "simulated"``.
    """

    #: (T, 2, 21, 3) predicted camera-frame joints (m); NaN where the slot is empty.
    joints_cam: np.ndarray
    #: (T, 2, 21, 2) predicted 2D keypoints (px, x right / y down); NaN where the slot is empty.
    joints_px: np.ndarray
    #: (T, 2) whether the slot holds a detection.
    present: np.ndarray
    #: (T, 2) detection confidence in [0, 1]; 0 where the slot is empty.
    confidence: np.ndarray
    #: (T,) frames on which the left/right labels were swapped by the simulator.
    injected_swap: np.ndarray
    #: (T, 2) slots left empty by a simulated miss (the ground-truth hand existed).
    missed: np.ndarray
    #: (T, 2) diagnostic: total factor s applied to the root along its viewing ray (the hand
    #: shown in the slot); NaN where the slot is empty.
    root_depth_scale: np.ndarray
    #: Label for the ``detector`` column of every table built from these outputs.
    detector: str = field(default=DETECTOR_NAME)


def _rotation_matrices(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues formula for (..., 3) axis-angle vectors; a zero vector gives the exact identity."""
    theta = np.linalg.norm(rotvec, axis=-1)
    safe = np.where(theta > 0, theta, 1.0)
    axis = np.where((theta > 0)[..., None], rotvec / safe[..., None], 0.0)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    kx = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                   np.stack([-y, x, zero], -1)], -2)
    s = np.sin(theta)[..., None, None]
    c1 = (1.0 - np.cos(theta))[..., None, None]
    return np.eye(3) + s * kx + c1 * (kx @ kx)


def _sample_runs(rng: np.random.Generator, n_series: int, n_frames: int, rate_hz: float,
                 fps: float, duration: tuple[int, int], what: str) -> np.ndarray:
    """Boolean (n_series, n_frames) runs from a renewal process with rate_hz events per second.

    Gaps between events are geometric (>= 1 frame) with mean fps / rate - mean duration, so the
    long-run event rate is exactly rate_hz; durations are uniform integers on ``duration``.
    """
    out = np.zeros((n_series, n_frames), dtype=bool)
    if rate_hz <= 0 or n_frames == 0:
        return out
    lo, hi = int(duration[0]), int(duration[1])
    mean_dur = 0.5 * (lo + hi)
    mean_gap = fps / rate_hz - mean_dur
    if mean_gap < 1.0:
        raise ValueError(
            f"{what}: rate {rate_hz} /s with mean duration {mean_dur} frames at {fps} fps leaves no "
            f"gap between events (need rate < fps / (mean duration + 1))")
    p_start = 1.0 / mean_gap
    if not p_start > 0.0:  # rate so small that fps / rate overflowed: no event in any take
        return out
    n_events = int(np.ceil(n_frames / (mean_gap + mean_dur) * 1.5)) + 16
    while True:
        # A gap longer than the take is equivalent to one of n_frames + 1 (clip: no overflow).
        gaps = np.minimum(rng.geometric(p_start, size=(n_series, n_events)), n_frames + 1)
        durs = rng.integers(lo, hi + 1, size=(n_series, n_events))
        # Event k starts after gaps 0..k and durations 0..k-1 (first possible start: frame gap-1).
        starts = np.cumsum(gaps, axis=1) + np.cumsum(durs, axis=1) - durs - 1
        if np.all(starts[:, -1] >= n_frames):
            break
        n_events *= 2
    ends = np.minimum(starts + durs, n_frames)
    keep = starts < n_frames
    rows = np.broadcast_to(np.arange(n_series)[:, None], starts.shape)
    diff = np.zeros((n_series, n_frames + 1), dtype=np.int64)
    np.add.at(diff, (rows[keep], starts[keep]), 1)
    np.add.at(diff, (rows[keep], ends[keep]), -1)
    out[:] = np.cumsum(diff[:, :n_frames], axis=1) > 0
    return out


def _ar1(rng: np.random.Generator, shape_series: tuple[int, ...], n_frames: int, std: float,
         phi: float) -> np.ndarray:
    """Stationary AR(1) series with marginal std ``std``: (n_frames, *shape_series)."""
    e = rng.standard_normal((n_frames, *shape_series))
    if std == 0:
        return np.zeros_like(e)
    e[1:] *= std * np.sqrt(1.0 - phi * phi)
    e[0] *= std  # start in the stationary distribution
    return lfilter([1.0], [1.0, -phi], e, axis=0)


def _frames_to_nearest(mask: np.ndarray) -> np.ndarray:
    """For (n, T) bool mask, the distance in frames to the nearest True along T (inf if none)."""
    n, t = mask.shape
    idx = np.arange(t, dtype=np.float64)
    last = np.where(mask, idx, -np.inf)
    last = np.maximum.accumulate(last, axis=1)
    nxt = np.where(mask, idx, np.inf)
    nxt = np.minimum.accumulate(nxt[:, ::-1], axis=1)[:, ::-1]
    return np.minimum(idx - last, nxt - idx)


def _validate(joints_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(joints_cam, dtype=np.float64)
    if x.ndim != 4 or x.shape[1:] != (2, N_JOINTS, 3):
        raise ValueError(f"joints_cam must have shape (T, 2, 21, 3), got {x.shape}")
    if x.shape[0] < 1:
        raise ValueError("joints_cam must hold at least one frame (T >= 1)")
    k = np.asarray(K, dtype=np.float64)
    if k.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {k.shape}")
    if not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ValueError("K must be finite with positive focal lengths fx = K[0,0], fy = K[1,1]")
    if not np.allclose(k[2], [0.0, 0.0, 1.0]) or k[1, 0] != 0:
        raise ValueError(f"K must be an upper-triangular pinhole matrix with last row (0, 0, 1), got {k.tolist()}")
    if np.any(np.isinf(x)):
        raise ValueError("joints_cam contains infinite values (use NaN for an absent hand)")
    nan = np.isnan(x).reshape(x.shape[0], 2, -1)
    absent = nan.all(axis=2)
    partial = nan.any(axis=2) & ~absent
    if np.any(partial):
        t, h = np.argwhere(partial)[0]
        raise ValueError(
            f"joints_cam frame {t} hand {h} is partly NaN: a hand must be all NaN (absent) or all finite")
    gt_present = ~absent
    z = x[..., 2]
    bad = gt_present[..., None] & ~(z > 0)
    if np.any(bad):
        t, h, j = np.argwhere(bad)[0]
        raise ValueError(
            f"joints_cam has non-positive depth z={z[t, h, j]!r} (frame {t}, hand {h}, joint {j}); "
            f"joints must lie in front of the camera (OpenCV frame, z forward)")
    return x, k, gt_present


def simulate_detections(joints_cam: np.ndarray, K: np.ndarray,
                        config: SimulatedDetectorConfig | None = None, seed: int | None = None,
                        *, fps: float | None = None) -> SimulatedDetections:
    """Turn ground-truth joints of one take into SIMULATED HaMeR-like detections.

    Args:
        joints_cam: (T, 2, 21, 3) ground-truth camera-frame joints (m), hand 0 = left, 1 = right,
            MediaPipe joint order; a hand that is absent on a frame is all NaN.
        K: (3, 3) camera intrinsics.
        config: error model parameters (defaults: :class:`SimulatedDetectorConfig`()).
        seed: random seed; ``None`` uses ``config.seed``.
        fps: frame rate of the take; ``None`` uses ``config.fps``.

    Returns:
        :class:`SimulatedDetections` (label its tables ``detector = "simulated"``).

    Raises:
        ValueError: wrong shapes, an invalid K, partly-NaN or infinite joints, non-positive depth,
            or event rates that do not fit the frame rate.
    """
    cfg = SimulatedDetectorConfig() if config is None else config
    if not isinstance(cfg, SimulatedDetectorConfig):
        raise ValueError(f"config must be a SimulatedDetectorConfig, got {type(cfg).__name__}")
    rate = cfg.fps if fps is None else float(fps)
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"fps must be finite and > 0, got {fps!r}")
    x, k, gt_present = _validate(joints_cam, K)
    n_t = x.shape[0]
    seed_val = cfg.seed if seed is None else seed
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed_val)).spawn(9)]
    (rng_noise, rng_rot, rng_scale, rng_depth, rng_pix, rng_swap, rng_miss, rng_conf,
     _spare) = streams

    # Absent hands are computed on a dummy point in front of the camera and masked at the end.
    xs = np.where(gt_present[..., None, None], x, np.array([0.0, 0.0, 1.0]))
    root = xs[:, :, :1, :]                               # (T, 2, 1, 3) wrist
    rel = xs - root

    # 1. hand-local joint noise accumulated along the kinematic tree.
    inc = rng_noise.standard_normal((n_t, 2, N_JOINTS, 3)) * (cfg.joint_noise_std_m / _CHAIN_NORM)
    noise = np.einsum("jk,thkc->thjc", _ANCESTORS, inc)

    # 2. rotation jitter about the wrist (RMS angle = rotation_jitter_deg).
    rotvec = rng_rot.standard_normal((n_t, 2, 3)) * (np.deg2rad(cfg.rotation_jitter_deg) / np.sqrt(3.0))
    rot = _rotation_matrices(rotvec)                     # (T, 2, 3, 3)
    # delta = S - (X - r) with S = R (X - r) + n; exact zeros when R = I and n = 0.
    delta = np.einsum("thab,thjb->thja", rot - np.eye(3), rel) + noise

    # 3. scale error (per-take bias + per-frame jitter), per hand.
    log_c = (rng_scale.standard_normal((1, 2)) * cfg.scale_error_log_std
             + rng_scale.standard_normal((n_t, 2)) * cfg.scale_jitter_log_std)
    c = np.exp(log_c)

    # 4. depth factor: focal mismatch (bias + OU walk + jitter) times the scale error.
    phi = float(np.exp(-1.0 / (cfg.depth_walk_tau_s * rate)))
    log_g = (np.log(cfg.depth_ratio)
             + rng_depth.standard_normal((1, 2)) * cfg.depth_bias_log_std
             + _ar1(rng_depth, (2,), n_t, cfg.depth_walk_log_std, phi)
             + rng_depth.standard_normal((n_t, 2)) * cfg.depth_jitter_log_std)
    s = np.exp(log_g) * c
    cc = c[..., None, None]
    # joints = s r + c S, written so that zero error returns X bit-exactly.
    pred = xs + cc * delta + (cc - 1.0) * rel + (s[..., None, None] - 1.0) * root

    # 5. 2D keypoints from the noisy hand at its true position.
    px = project_points(xs + delta, k)
    px = px + rng_pix.standard_normal(px.shape) * cfg.pixel_noise_px

    # 7. misses per physical hand (sampled before the swap, then carried with the hand).
    miss_phys = _sample_runs(rng_miss, 2, n_t, cfg.miss_rate_hz, rate, cfg.miss_duration_frames,
                             "miss_rate_hz").T & gt_present
    present_phys = gt_present & ~miss_phys

    # 8. confidence per physical hand (swap drop applied after the swap).
    conf = cfg.conf_base + rng_conf.standard_normal((n_t, 2)) * cfg.conf_noise_std
    if cfg.near_miss_conf_drop > 0 and cfg.near_miss_frames > 0 and miss_phys.any():
        d = _frames_to_nearest(miss_phys.T).T
        conf = conf - cfg.near_miss_conf_drop * np.clip(1.0 - d / (cfg.near_miss_frames + 1), 0.0, 1.0)

    # 6. left/right swaps, only where both hands exist in the ground truth.
    swap = _sample_runs(rng_swap, 1, n_t, cfg.swap_rate_hz, rate, cfg.swap_duration_frames,
                        "swap_rate_hz")[0] & gt_present.all(axis=1)
    src = np.where(swap[:, None], np.array([1, 0]), np.array([0, 1]))  # (T, 2) physical hand per slot
    tt = np.arange(n_t)[:, None]
    pred, px = pred[tt, src], px[tt, src]
    present, missed = present_phys[tt, src], miss_phys[tt, src]
    conf, s_slot = conf[tt, src], s[tt, src]
    conf = conf - cfg.swap_conf_drop * swap[:, None]
    conf = np.where(present, np.clip(conf, 0.0, 1.0), 0.0)

    pred = np.where(present[..., None, None], pred, np.nan)
    px = np.where(present[..., None, None], px, np.nan)
    s_slot = np.where(present, s_slot, np.nan)
    return SimulatedDetections(
        joints_cam=pred, joints_px=px, present=present, confidence=conf,
        injected_swap=swap, missed=missed, root_depth_scale=s_slot)
