"""Outcome stability of the robot check: does an episode's verdict survive a physically irrelevant change?

A rigid shift of the whole scene along the table (every object and every gripper pose moved by the
same offset) changes nothing physical: contacts, gravity and the table top are translation-invariant
(the table is 1.5 m x 0.9 m; the offsets are fractions of a millimetre). Only the floating-point rounding of the
simulation changes. An episode whose outcome flips under such a shift is decided by numerical chaos,
not by the trajectory, and its single-run verdict is not a reliable label for training or for a
success rate: its success is a probability, estimated by the share of repeats that succeed.

    offsets = scene_offsets(episode_ids, repeats=5, jitter_m=1e-4, seed=0)  # (n, 5, 3); repeat 0 = 0
    kp2, actions2 = shift_scene(keypoints, actions, offsets[i, r])
    summary = stability_summary(success)                                    # success: (n, repeats) bool
"""

from __future__ import annotations

import numpy as np


def scene_offsets(episode_ids, repeats: int, jitter_m: float, seed: int = 0) -> np.ndarray:
    """(n_episodes, repeats, 3) rigid scene offsets in metres: repeat 0 is the unshifted scene (the run
    `simulate` checks), the others are normal draws in x and y with standard deviation jitter_m (z = 0:
    objects stay on the table). Each episode's draws depend only on (seed, episode id), so they do not
    change with the chunking or with which other episodes a run checks."""
    if repeats < 2:
        raise ValueError(f"repeats must be at least 2 (the unshifted run and one shifted), got {repeats}")
    if not (np.isfinite(jitter_m) and jitter_m > 0):
        raise ValueError(f"jitter_m must be a positive number of metres, got {jitter_m}")
    ids = np.asarray(episode_ids, dtype=np.int64).reshape(-1)
    off = np.zeros((len(ids), int(repeats), 3))
    for i, e in enumerate(ids):
        off[i, 1:, :2] = np.random.default_rng((int(seed), int(e))).normal(0.0, jitter_m, (int(repeats) - 1, 2))
    return off


def shift_scene(keypoints, actions, offset) -> tuple[np.ndarray, np.ndarray]:
    """The scene moved rigidly by offset (3,): object keypoints (K, 3) and the gripper positions of the
    (n, 2, 8) actions shifted; orientations and gripper states unchanged. Returns float64 copies."""
    kp = np.array(keypoints, dtype=np.float64)
    a = np.array(actions, dtype=np.float64)
    off = np.asarray(offset, dtype=np.float64)
    if off.shape != (3,):
        raise ValueError(f"offset must have shape (3,), got {off.shape}")
    kp += off
    a[..., :3] += off
    return kp, a


def stability_summary(success) -> dict:
    """Summary of an (n_episodes, repeats) success matrix whose column 0 is the unshifted run."""
    s = np.asarray(success, dtype=bool)
    if s.ndim != 2 or s.shape[1] < 2:
        raise ValueError(f"success must be (n_episodes, repeats >= 2), got shape {s.shape}")
    always = s.all(axis=1)
    never = ~s.any(axis=1)
    n = s.shape[0]
    return {"episodes": n, "repeats": int(s.shape[1]),
            "first_run_success_rate": float(s[:, 0].mean()) if n else float("nan"),
            "success_rate": float(s.mean()) if n else float("nan"),
            "always": int(always.sum()), "never": int(never.sum()), "flipping": int(n - always.sum() - never.sum())}
