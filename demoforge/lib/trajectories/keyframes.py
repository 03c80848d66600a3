"""Keyframe encoding of (T, 2, 8) action sequences: the steps a trajectory cannot do without.

    idx = encode_keyframes(actions)                       # (K,) step indices, first and last included
    back = decode_keyframes(actions[idx], idx, len(actions))   # (T, 2, 8), within tolerance of actions

Encoding (bounded reconstruction error, greedy)
    From an anchor keyframe a, the segment [a, b] is extended step by step while, at every step i
    strictly between a and b and for both arms, the linearly interpolated position is within
    ``pos_tol_m`` of the real one and the slerped orientation within ``rot_tol_rad`` of it; the last
    b that passed becomes the next keyframe and the next anchor.  A segment never runs past a forced
    keyframe:
      * the first and the last step;
      * every gripper open/close instant, on both sides: for a step i whose open state (g >= 0.5, any
        arm) differs from step i - 1, both i - 1 and i are keyframes, so the decoder (which holds g
        between keyframes) reproduces the change at exactly the same step with the same poses;
      * optional ``boundaries`` (motion/skill segment starts, clipped to the episode).

Smoothing before encoding (recorded demonstrations)
    An ingested trajectory carries per-frame jitter from the detector (on the default synthetic takes
    a step lies a median 9 mm and 0.10 rad from the midpoint of its neighbours), above any useful
    tolerance, so the bounded-error encoder would keep nearly every step.  :func:`keyframe_actions`
    therefore first smooths the poses with a Gaussian over time (:func:`smooth_actions`: positions
    averaged, quaternions averaged on one hemisphere and renormalised, gripper values untouched, each
    run between gripper changes on its own so a grasp pose is not averaged with the lift after it) and
    encodes the smoothed sequence; its keyframes are the smoothed poses.  A scripted (clean)
    trajectory is changed by the smoothing only where it turns, by far less than the tolerance.

Decoding (the robot executor's interpolation)
    ``lib/sim/executor.py`` drives the grippers between consecutive action steps with linear
    positions and slerped rotations (``interpolate_poses(..., rotation="slerp", position="linear")``,
    its default ``SimOptions.position_interp``).  :func:`decode_keyframes` fills the steps between
    keyframes with the same interpolation; the gripper value of a step is that of the last keyframe
    at or before it (held, a step function).  Slerp at uniform fractions lies on one geodesic at
    constant speed, so executing the decoded steps moves the grippers exactly as interpolating the
    keyframes themselves would.

Times of an LLM answer (the design choice)
    Appendix A's layout has 8 values per gripper and no time column, and it is kept: an answer is K
    keyframes without times.  The prompt's examples are encoded one by one, and the answer is
    decoded on the time grid of the most similar example, the one placed last in the prompt next to
    the new input (its keyframe count is the count the prompt asks for):
    :func:`answer_times` scales that example's keyframe times (as fractions of its length) to the
    answer's episode length; an answer with another keyframe count is spread over the same time
    curve by linear interpolation in keyframe index.  The database's episodes of one layout share one
    plan, so the scaled times are usually the example's integer steps unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from demoforge.lib.geometry import interpolate_poses, quat_angle, quat_normalize, quat_slerp
from demoforge.lib.geometry.interpolation import hemisphere_continuous

__all__ = ["encode_keyframes", "decode_keyframes", "answer_times", "keyframe_fractions", "reconstruction_error",
           "gripper_change_steps", "smooth_actions", "keyframe_actions", "KeyframeSettings", "DEFAULT_KEYFRAMES"]


@dataclass(frozen=True)
class KeyframeSettings:
    """How an action sequence becomes keyframes (:func:`keyframe_actions`): the reconstruction
    tolerances of the encoder (metres, radians) and the Gaussian smoothing before it (sigma in steps;
    0 = none)."""

    pos_tol_m: float = 0.01
    rot_tol_rad: float = 0.1
    smooth_sigma_steps: float = 2.0

    def __post_init__(self):
        if not (self.pos_tol_m >= 0 and self.rot_tol_rad >= 0 and self.smooth_sigma_steps >= 0):
            raise ValueError(f"keyframe tolerances and smoothing must be >= 0, got {self}")


# what the prompts, the answers' decoding and the round-trip measurement use unless told otherwise
# (chosen by scripts/measure_keyframes.py: docs/results/issue-21-keyframes.md)
DEFAULT_KEYFRAMES = KeyframeSettings()


def _check(actions: Any) -> np.ndarray:
    a = np.asarray(actions, dtype=np.float64)
    if a.ndim != 3 or a.shape[1:] != (2, 8) or a.shape[0] < 1:
        raise ValueError(f"actions must be (T, 2, 8) with T >= 1, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("actions must be finite")
    return a


def gripper_change_steps(actions: Any) -> np.ndarray:
    """Steps i >= 1 whose open state (g >= 0.5) differs from step i - 1 in either arm."""
    g = np.asarray(actions, dtype=np.float64)[:, :, 7] >= 0.5
    return np.flatnonzero(np.any(g[1:] != g[:-1], axis=1)) + 1


def _segment_errors(pos: np.ndarray, quat: np.ndarray, a: int, b: int) -> tuple[float, float]:
    """Largest position / rotation error over the steps strictly between a and b, both arms, when they
    are interpolated between a and b as the decoder does."""
    if b - a < 2:
        return 0.0, 0.0
    h = (np.arange(a + 1, b, dtype=np.float64) - a) / (b - a)
    p = pos[a] + h[:, None, None] * (pos[b] - pos[a])
    q = quat_slerp(np.broadcast_to(quat[a], (len(h), 2, 4)), np.broadcast_to(quat[b], (len(h), 2, 4)),
                   np.broadcast_to(h[:, None], (len(h), 2)))
    dp = float(np.linalg.norm(p - pos[a + 1:b], axis=-1).max())
    dq = float(quat_angle(q, quat[a + 1:b]).max())
    return dp, dq


def encode_keyframes(actions: Any, pos_tol_m: float = 0.005, rot_tol_rad: float = 0.05,
                     boundaries: Sequence[int] | None = None) -> np.ndarray:
    """(K,) increasing step indices of the keyframes of a (T, 2, 8) action sequence (module docstring):
    decoding ``actions[idx]`` at ``idx`` is within ``pos_tol_m`` (metres) and ``rot_tol_rad`` (radians)
    of every step, and reproduces the gripper values exactly."""
    a = _check(actions)
    if not (pos_tol_m >= 0 and rot_tol_rad >= 0):
        raise ValueError("tolerances must be >= 0")
    T = a.shape[0]
    if T == 1:
        return np.zeros(1, dtype=np.int64)
    forced = {0, T - 1}
    ch = gripper_change_steps(a)
    forced.update(ch.tolist())
    forced.update((ch - 1).tolist())
    if boundaries is not None:
        b = np.asarray(list(boundaries), dtype=np.int64)
        forced.update(b[(b >= 0) & (b < T)].tolist())
    forced_sorted = np.array(sorted(forced), dtype=np.int64)
    pos = a[:, :, :3]
    quat = quat_normalize(a[:, :, 3:7])
    keep = [0]
    anchor = 0
    while anchor < T - 1:
        limit = int(forced_sorted[np.searchsorted(forced_sorted, anchor, side="right")])
        end = anchor + 1  # the next step always reproduces itself
        while end < limit:
            dp, dq = _segment_errors(pos, quat, anchor, end + 1)
            if dp > pos_tol_m or dq > rot_tol_rad:
                break
            end += 1
        keep.append(end)
        anchor = end
    return np.asarray(keep, dtype=np.int64)


def smooth_actions(actions: Any, sigma_steps: float) -> np.ndarray:
    """(T, 2, 8) actions with positions and orientations smoothed over time by a Gaussian of
    ``sigma_steps`` steps; gripper values unchanged.  Each run between gripper open/close changes is
    smoothed on its own (its ends repeated outward), so a grasp pose is never averaged with the
    motion after the grasp.  Quaternions are made hemisphere-continuous, averaged with the same
    weights and renormalised (accurate for the small angles within a few sigma of each other)."""
    from scipy.ndimage import gaussian_filter1d

    a = _check(actions)
    if not sigma_steps >= 0:
        raise ValueError(f"sigma_steps must be >= 0, got {sigma_steps}")
    out = a.copy()
    if sigma_steps == 0 or a.shape[0] < 3:
        return out
    q_all = hemisphere_continuous(quat_normalize(a[:, :, 3:7]))
    cuts = [0, *gripper_change_steps(a).tolist(), a.shape[0]]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        if s1 - s0 < 3:
            continue
        out[s0:s1, :, :3] = gaussian_filter1d(a[s0:s1, :, :3], float(sigma_steps), axis=0, mode="nearest")
        out[s0:s1, :, 3:7] = quat_normalize(gaussian_filter1d(q_all[s0:s1], float(sigma_steps), axis=0, mode="nearest"))
    return out


def keyframe_actions(actions: Any, settings: KeyframeSettings = DEFAULT_KEYFRAMES,
                     boundaries: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The keyframes of a (T, 2, 8) action sequence as written in a prompt: ((K, 2, 8) values, (K,)
    step indices).  The sequence is smoothed (``settings.smooth_sigma_steps``), then encoded with the
    settings' tolerances; the values are the smoothed poses at the kept steps (gripper values exact)."""
    smooth = smooth_actions(actions, settings.smooth_sigma_steps)
    idx = encode_keyframes(smooth, settings.pos_tol_m, settings.rot_tol_rad, boundaries)
    return smooth[idx], idx


def decode_keyframes(keyframes: Any, times: Any, n_steps: int) -> np.ndarray:
    """(n_steps, 2, 8) actions at steps 0..n_steps-1 from (K, 2, 8) keyframes at increasing (K,) step
    times (fractional allowed): positions linear, rotations slerp, gripper value held from the last
    keyframe at or before the step; steps outside [times[0], times[-1]] take the end keyframes."""
    kf = _check(keyframes)
    t = np.asarray(times, dtype=np.float64)
    n = int(n_steps)
    if t.shape != (kf.shape[0],):
        raise ValueError(f"times must be ({kf.shape[0]},), got {t.shape}")
    if n < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    steps = np.arange(n, dtype=np.float64)
    pos, quat = interpolate_poses(t, kf[:, :, :3], kf[:, :, 3:7], steps, rotation="slerp", position="linear")
    k = np.clip(np.searchsorted(t, steps, side="right") - 1, 0, kf.shape[0] - 1)
    out = np.empty((n, 2, 8), dtype=np.float64)
    out[:, :, :3] = pos
    out[:, :, 3:7] = quat
    out[:, :, 7] = kf[k, :, 7]
    # the keyframes themselves exactly (no interpolation round-off at their own steps)
    exact = (t == np.round(t)) & (t >= 0) & (t <= n - 1)
    out[np.round(t[exact]).astype(int)] = kf[exact]
    return out


def reconstruction_error(actions: Any, decoded: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-step (T,) largest position error (m) and rotation error (rad) over both arms."""
    a, d = _check(actions), _check(decoded)
    dp = np.linalg.norm(a[:, :, :3] - d[:, :, :3], axis=-1).max(axis=1)
    dq = quat_angle(quat_normalize(a[:, :, 3:7]), quat_normalize(d[:, :, 3:7])).max(axis=1)
    return dp, dq


def keyframe_fractions(indices: Any, n_steps: int) -> np.ndarray:
    """Keyframe step indices as fractions of the episode, 0 = first step, 1 = last."""
    idx = np.asarray(indices, dtype=np.float64)
    return idx / max(int(n_steps) - 1, 1)


def answer_times(fractions: Any, n_keyframes: int, n_steps: int) -> np.ndarray:
    """(n_keyframes,) strictly increasing step times for an answer of n_keyframes keyframes decoded
    into n_steps steps, on the time curve of the example whose keyframe ``fractions`` are given (module
    docstring): the same count takes the example's times scaled to n_steps; another count is spread
    over that curve by linear interpolation in keyframe index (first -> 0, last -> n_steps - 1)."""
    f = np.asarray(fractions, dtype=np.float64)
    m = int(n_keyframes)
    if m < 1:
        raise ValueError(f"n_keyframes must be >= 1, got {n_keyframes}")
    if m == 1 or f.size < 2:
        return np.linspace(0.0, n_steps - 1.0, m) if m > 1 else np.zeros(1)
    if m != f.size:
        f = np.interp(np.linspace(0.0, f.size - 1.0, m), np.arange(f.size, dtype=np.float64), f)
    t = (f - f[0]) / (f[-1] - f[0]) * (n_steps - 1.0)
    t = np.round(t, 9)  # scaled integer steps stay integers (exact keyframe copies in the decoder)
    if np.any(np.diff(t) <= 0):  # more keyframes than steps, or a degenerate curve: spread evenly
        t = np.linspace(0.0, n_steps - 1.0, m)
    return t
