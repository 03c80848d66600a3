"""Episodes of a task database -> fixed-size training arrays for the policy.

Every episode's action sequence is time-resampled to the prompts' waypoint count with the prompts'
own rule (demoforge.lib.llm.prompting.resample_actions: first/last step and gripper-change steps kept exactly,
the rest spread proportionally, linear positions, slerp rotations).  :func:`resample_batch` gives
the same result for a whole batch at once: episodes that share a length and gripper-change steps
(all translated episodes of a database do, all mirrored ones do) share the waypoint times, so the
times are computed once per group and the interpolation is one vectorised call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.geometry import interpolate_poses, quat_normalize
from demoforge.lib.llm.prompting import waypoint_times
from demoforge.lib.policy.rotation6d import quat_to_6d

POS_STD_FLOOR = 0.01  # m: features that hardly vary (table-height z) must not blow up when normalised


def resample_batch(actions: np.ndarray, lengths: np.ndarray, n_waypoints: int = 20) -> np.ndarray:
    """(B, L, 2, 8) padded action sequences with (B,) true lengths -> (B, n_waypoints, 2, 8), equal
    (to float round-off) to calling resample_actions on every episode."""
    a = np.asarray(actions)
    lengths = np.asarray(lengths, int)
    if a.ndim != 4 or a.shape[2:] != (2, 8) or len(lengths) != len(a):
        raise ValueError(f"actions must be (B, L, 2, 8) with one length per episode, got {a.shape} and {lengths.shape}")
    if len(a) and (lengths.min() < 1 or lengths.max() > a.shape[1]):
        raise ValueError(f"lengths must lie in [1, {a.shape[1]}], got {lengths.min()}..{lengths.max()}")
    out = np.empty((len(a), n_waypoints, 2, 8))
    g_open = a[..., 7] >= 0.5  # (B, L, 2)
    # one group per (length, gripper-change pattern): a hash of the state sequence up to the length
    step = np.arange(a.shape[1])
    masked = np.where(step[None, :, None] < lengths[:, None, None], g_open, False)
    packed = np.packbits(masked.reshape(len(a), -1), axis=1)
    keys = np.concatenate([lengths[:, None].astype(np.int64).view(np.uint8).reshape(len(a), -1), packed], axis=1)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    for gi in np.unique(group):
        rows = np.flatnonzero(group == gi)
        n = int(lengths[rows[0]])
        qt = waypoint_times(g_open[rows[0], :n], n_waypoints)
        ga = a[rows, :n].astype(np.float64).transpose(1, 0, 2, 3)  # time first: (n, b, 2, 8)
        if n == 1:
            pos, quat = np.repeat(ga[:, :, :, :3], n_waypoints, 0), np.repeat(quat_normalize(ga[:, :, :, 3:7]), n_waypoints, 0)
        else:
            pos, quat = interpolate_poses(np.arange(n, dtype=np.float64), ga[..., :3], ga[..., 3:7], qt,
                                          rotation="slerp", position="linear")
        res = np.empty((n_waypoints, len(rows), 2, 8))
        res[..., :3], res[..., 3:7] = pos, quat
        nearest = np.clip(np.floor(qt + 0.5).astype(int), 0, n - 1)
        res[..., 7] = g_open[rows][:, nearest].transpose(1, 0, 2)
        exact = qt == np.round(qt)  # exact copies at integer times, as resample_actions
        idx = np.round(qt[exact]).astype(int)
        res[exact, ..., :7] = ga[idx, ..., :7]
        res[exact, ..., 3:7] = quat_normalize(ga[idx, ..., 3:7])
        out[rows] = res.transpose(1, 0, 2, 3)
    return out


@dataclass
class PolicyData:
    """One task database as arrays: inputs (keypoints, initial poses), targets (waypoints), and what
    the split needs (placement ids, episode kinds)."""

    episode_id: np.ndarray   # (N,)
    kind: np.ndarray         # (N,) original / translated / mirrored
    placement: np.ndarray    # (N, n_obj, 3) the sampled transform of each episode ([dx, dy, dyaw] per object)
    keypoints: np.ndarray    # (N, k, 3)
    initial: np.ndarray      # (N, 2, 8)
    waypoints: np.ndarray    # (N, n_waypoints, 2, 8)

    def __len__(self) -> int:
        return len(self.episode_id)

    def subset(self, idx) -> "PolicyData":
        return PolicyData(*(getattr(self, f)[idx] for f in
                            ("episode_id", "kind", "placement", "keypoints", "initial", "waypoints")))


def split_by_placement(data: PolicyData, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train_idx, val_idx): episodes with the same sampled placement (kind + transform) always land on
    the same side, so validation scenes are placements the network never saw.  The original
    demonstration is always in training."""
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
    key = np.concatenate([np.round(data.placement.reshape(len(data), -1), 6),
                          np.unique(data.kind, return_inverse=True)[1][:, None].astype(float)], axis=1)
    _, group = np.unique(key, axis=0, return_inverse=True)
    n_groups = group.max() + 1 if len(group) else 0
    rng = np.random.default_rng([int(seed), 31337])
    val_groups = rng.permutation(n_groups)[: int(round(val_fraction * n_groups))]
    is_val = np.isin(group, val_groups) & (data.kind != "original")
    if is_val.all() or not is_val.any():
        raise ValueError(f"{len(data)} episodes in {n_groups} placements cannot be split {1 - val_fraction:.0%}/"
                         f"{val_fraction:.0%}: use more episodes or another val_fraction")
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def pose_features(poses: np.ndarray) -> np.ndarray:
    """(..., 8) poses -> (..., 10) features [x, y, z, 6D rotation, g]."""
    p = np.asarray(poses, np.float64)
    return np.concatenate([p[..., :3], quat_to_6d(quat_normalize(p[..., 3:7])), p[..., 7:8]], axis=-1)


@dataclass
class Normalizer:
    """Per-feature mean / std of the positions (keypoints, initial positions, waypoint positions),
    taken from the training split; rotations (6D) and gripper states are already unit-scale."""

    kp_mean: np.ndarray
    kp_std: np.ndarray
    init_mean: np.ndarray
    init_std: np.ndarray
    wp_mean: np.ndarray
    wp_std: np.ndarray

    @classmethod
    def fit(cls, data: PolicyData) -> "Normalizer":
        def ms(x):
            return x.mean(0), np.maximum(x.std(0), POS_STD_FLOOR)

        return cls(*ms(data.keypoints), *ms(data.initial[..., :3]), *ms(data.waypoints[..., :3]))
