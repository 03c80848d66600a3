"""The objects' keypoints at every step of an episode, for exports that carry an environment state.

An episode stores its scene only at its start (episodes.object_keypoints, 11 x 3). A policy needs
to see where the objects are while they move, so every step gets the keypoints carried by the
grippers: each object is handled by one arm (the rule of :func:`demoforge.lib.trajectories.segmentation.infer_object_arm`
applied to the episode itself: the arm that holds it for the most frames, holding = closed on the
object nearest the pinch point when the gripper closed; an object never held goes to the arm that
holds nothing else), so mirrored episodes swap the arms by themselves. While that arm's gripper is
closed (g < 0.5, the executor's threshold) the object moves rigidly with the gripper from the pose
it had when the gripper closed; after the gripper opens it stays where it was released (no fall
under gravity, no pushing by the other object: the kinematic scene of the task library's scripted
demonstrations). On the six scripted demonstrations, plain and mirrored, this reproduces the task
library's own per-frame object keypoints exactly (tests/lib/exports/test_object_state.py).

Vectorised over all episodes at once: the grasps (runs of a closed gripper) are handled by their
rank within the episode (first grasp of every episode, then the second ...), so the loop runs as
many times as the most grasps one arm makes in one episode (one, in the task library).
"""

from __future__ import annotations

import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.exports import ExportError, episode_starts


def _grasps(closed: np.ndarray, ep: np.ndarray, first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(start, end exclusive) of every run of ``closed`` frames, runs cut at episode starts."""
    prev = np.concatenate([[False], closed[:-1]])
    onset = closed & (first | ~prev)
    nxt = np.concatenate([closed[1:], [False]])
    last = np.concatenate([first[1:], [True]])
    offset = closed & (last | ~nxt)
    return np.flatnonzero(onset), np.flatnonzero(offset) + 1


def object_arms(poses: np.ndarray, lengths: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray
                ) -> np.ndarray:
    """(N, n_objects) the arm (0 left, 1 right) handling each object of each episode
    (:func:`demoforge.lib.trajectories.segmentation.infer_object_arm`'s rule, vectorised over the episodes)."""
    ko = np.asarray(keypoint_object, int)
    n, n_obj = len(lengths), int(ko.max()) + 1
    starts = episode_starts(lengths)
    ep = np.repeat(np.arange(n), lengths)
    first = np.zeros(len(poses), bool)
    first[starts] = True
    counts = np.zeros((n, n_obj, 2), np.int64)
    for arm in (0, 1):
        s, e = _grasps(poses[:, arm, 7] < 0.5, ep, first)
        if len(s) == 0:
            continue
        d = np.linalg.norm(keypoints0[ep[s]] - poses[s, arm, None, :3], axis=-1)           # (runs, K)
        per_obj = np.stack([np.where(ko == o, d, np.inf).min(axis=1) for o in range(n_obj)], axis=1)
        np.add.at(counts, (ep[s], per_obj.argmin(axis=1), arm), e - s)
    arm_of = counts.argmax(axis=2)
    held = counts.max(axis=2) > 0
    for o in range(n_obj):  # never held: the arm that holds nothing else (or arm 0)
        others = np.delete(np.arange(n_obj), o)
        used = [((arm_of[:, others] == a) & held[:, others]).any(axis=1) for a in (0, 1)]
        arm_of[:, o] = np.where(held[:, o], arm_of[:, o], np.where(~used[0], 0, np.where(~used[1], 1, 0)))
    return arm_of


def episode_object_keypoints(poses: np.ndarray, lengths: np.ndarray, keypoints0: np.ndarray,
                             keypoint_object: np.ndarray) -> np.ndarray:
    """(F, K, 3) object keypoints per step of concatenated episodes.

    poses: (F, 2, 8) concatenated episodes [x, y, z, qx, qy, qz, qw, g] per arm; lengths: (N,);
    keypoints0: (N, K, 3) each episode's keypoints at its first step, world m; keypoint_object:
    (K,) the object of each keypoint.
    """
    poses = np.asarray(poses, np.float64)
    lengths = np.asarray(lengths, np.int64)
    keypoints0 = np.asarray(keypoints0, np.float64)
    ko = np.asarray(keypoint_object, int)
    n = len(lengths)
    if keypoints0.ndim != 3 or keypoints0.shape[0] != n or keypoints0.shape[1:] != (len(ko), 3):
        raise ExportError(f"object keypoints must be (episodes={n}, {len(ko)}, 3), got {keypoints0.shape}")
    if not np.isfinite(keypoints0).all():
        raise ExportError("object keypoints contain NaN or inf; re-run `demoforge augment` for the task")
    starts = episode_starts(lengths)
    ends = starts + lengths
    ep = np.repeat(np.arange(n), lengths)
    first = np.zeros(len(poses), bool)
    first[starts] = True
    arm_of = object_arms(poses, lengths, keypoints0, ko)
    out = keypoints0[ep]                                                                 # (F, K, 3), a copy
    for arm in (0, 1):
        s, e = _grasps(poses[:, arm, 7] < 0.5, ep, first)
        if len(s) == 0:
            continue
        i = ep[s]
        mine = arm_of[i] == arm                                                          # (runs, n_obj)
        # the object a grasp carries: the nearest of the arm's objects when it closes (the arm's
        # only one in the task library)
        d = np.linalg.norm(keypoints0[i] - poses[s, arm, None, :3], axis=-1)
        per_obj = np.stack([np.where(ko == o, d, np.inf).min(axis=1) for o in range(arm_of.shape[1])], axis=1)
        per_obj[~mine] = np.inf
        carried = np.where(mine.any(axis=1), per_obj.argmin(axis=1), -1)
        rank = np.arange(len(s)) - np.searchsorted(s, starts[i])                         # grasp number in episode
        for r in range(int(rank.max()) + 1):
            for o in np.unique(carried[(rank == r) & (carried >= 0)]):
                sel = np.flatnonzero((rank == r) & (carried == o))
                idx = np.flatnonzero(ko == o)
                L = e[sel] - s[sel]
                frames = np.repeat(s[sel], L) + (np.arange(L.sum()) - np.repeat(np.cumsum(L) - L, L))
                run_of = np.repeat(np.arange(len(sel)), L)
                # the object in the gripper's frame at the grasp, then carried: p(t) = R(t) local + x(t)
                R0 = geo.quat_to_matrix(poses[s[sel], arm, 3:7])                          # (runs, 3, 3)
                local = np.einsum("rji,rkj->rki", R0, out[s[sel]][:, idx] - poses[s[sel], arm, None, :3])
                Rt = geo.quat_to_matrix(poses[frames, arm, 3:7])                          # (frames, 3, 3)
                lf = local[run_of]                                                        # (frames, k, 3)
                moved = np.empty_like(lf)
                for a in range(3):  # three fused row products: far faster than batched 3x3 matmuls
                    moved[..., a] = (Rt[:, a, 0, None] * lf[..., 0] + Rt[:, a, 1, None] * lf[..., 1]
                                     + Rt[:, a, 2, None] * lf[..., 2] + poses[frames, arm, a, None])
                out[frames[:, None], idx[None, :]] = moved
                # after the release the object stays where it was let go, to the end of the episode
                H = ends[ep[s[sel]]] - e[sel]
                after = np.repeat(e[sel], H) + (np.arange(H.sum()) - np.repeat(np.cumsum(H) - H, H))
                out[after[:, None], idx[None, :]] = out[(e[sel] - 1)[np.repeat(np.arange(len(sel)), H)][:, None],
                                                        idx[None, :]]
    return out
