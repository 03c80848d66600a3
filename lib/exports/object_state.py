"""The objects' keypoints at every step of an episode, for exports that carry an environment state.

An episode stores its scene only at its start (episodes.object_keypoints, 11 x 3). A policy needs
to see where the objects are while they move, so every step gets the keypoints carried by the
grippers: each object is handled by one arm (:func:`lib.segmentation.infer_object_arm` on the
episode itself, so mirrored episodes swap the arms by themselves), and while that arm's gripper is
closed (g < 0.5, the executor's threshold) the object moves rigidly with the gripper from the pose
it had when the gripper closed; after the gripper opens it stays where it was released (no fall
under gravity, no pushing by the other object: the kinematic scene of the task library's scripted
demonstrations). On the six scripted demonstrations, plain and mirrored, this reproduces the task
library's own per-frame object keypoints exactly (tests/test_exports.py).
"""

from __future__ import annotations

import numpy as np

from lib.exports import ExportError, episode_starts


def episode_object_keypoints(poses: np.ndarray, lengths: np.ndarray, keypoints0: np.ndarray,
                             keypoint_object: np.ndarray) -> np.ndarray:
    """(F, K, 3) object keypoints per step of concatenated episodes.

    poses: (F, 2, 8) concatenated episodes [x, y, z, qx, qy, qz, qw, g] per arm; lengths: (N,);
    keypoints0: (N, K, 3) each episode's keypoints at its first step, world m; keypoint_object:
    (K,) the object of each keypoint. A loop over episodes (each one's carry is a few array ops).
    """
    from lib.segmentation import held_objects, infer_object_arm, object_keypoints_over_time

    poses = np.asarray(poses, np.float64)
    keypoints0 = np.asarray(keypoints0, np.float64)
    ko = np.asarray(keypoint_object, int)
    n = len(lengths)
    if keypoints0.ndim != 3 or keypoints0.shape[0] != n or keypoints0.shape[1:] != (len(ko), 3):
        raise ExportError(f"object keypoints must be (episodes={n}, {len(ko)}, 3), got {keypoints0.shape}")
    if not np.isfinite(keypoints0).all():
        raise ExportError("object keypoints contain NaN or inf; re-run `demoforge augment` for the task")
    out = np.empty((len(poses), len(ko), 3))
    for i, (s, L) in enumerate(zip(episode_starts(lengths).tolist(), np.asarray(lengths).tolist())):
        traj, kp = poses[s:s + L], keypoints0[i]
        arm_of = infer_object_arm(traj, kp, ko)
        nearest = held_objects(traj, kp, ko)  # used only when one arm handles several objects
        held = np.full((L, 2), -1)
        for arm in (0, 1):
            mine = np.flatnonzero(arm_of == arm)
            if len(mine) == 0:
                continue
            closed = traj[:, arm, 7] < 0.5
            obj = mine[0] if len(mine) == 1 else np.where(np.isin(nearest[:, arm], mine), nearest[:, arm], mine[0])
            held[:, arm] = np.where(closed, obj, -1)
        out[s:s + L] = object_keypoints_over_time(traj, kp, ko, held)
    return out
