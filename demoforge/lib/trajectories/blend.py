"""The `knn_blend` baseline: the k retrieved episodes carried to the query scene in their objects'
frames, then averaged.

Carrying an episode: the episode (actions (L, 2, 8), keypoints (K, 3)) is treated as a demonstration
of its own scene and re-targeted to the query scene by the augmentation's transform
(demoforge.lib.trajectories.augmentation.transform_demo, mode "object"): every skill segment follows its object exactly
(the gripper pose relative to that object is kept), motion segments blend between the objects they
leave and approach. Segments are the demonstration's (arms swapped for a mirrored episode; mode
"object" keeps the timing, so the frames are the same).

Averaging (per step and arm): positions by the mean, rotations by the normalised sign-aligned
quaternion mean (exact enough for rotations a few degrees apart, which the carried neighbours are),
gripper state by majority (ties: open). Only neighbours with the nearest one's mirroring are
blended: a mirrored and a plain episode have their arms' roles swapped.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib.trajectories.augmentation import DemoSource, mirror_source, transform_demo


def carry_episode(source, actions: np.ndarray, keypoints: np.ndarray, mirrored: bool,
                  query_object_poses: np.ndarray) -> np.ndarray:
    """One episode of source's database carried to a scene with object poses (n_obj, 4, 4)."""
    base = mirror_source(source) if mirrored else source
    ep = DemoSource(task=base.task, trajectory=np.asarray(actions, float), keypoints=np.asarray(keypoints, float),
                    keypoint_object=base.keypoint_object, keypoints_local=base.keypoints_local,
                    segments=list(base.segments), object_arm=base.object_arm, mirrored=base.mirrored,
                    mirror_perm=base.mirror_perm, workspace=base.workspace)
    return transform_demo(ep, query_object_poses, mode="object")


def average_trajectories(trajectories: list[np.ndarray]) -> np.ndarray:
    """(L, 2, 8) mean of several (L_i, 2, 8) trajectories (shorter ones padded with their last step)."""
    if not trajectories:
        raise ValueError("nothing to average")
    L = max(len(t) for t in trajectories)
    a = np.stack([np.concatenate([t, np.repeat(t[-1:], L - len(t), axis=0)]) if len(t) < L else t
                  for t in (np.asarray(t, float) for t in trajectories)])  # (k, L, 2, 8)
    out = np.empty(a.shape[1:])
    out[..., :3] = a[..., :3].mean(0)
    q = a[..., 3:7]
    sign = np.where(np.einsum("kla,la->kl", q.reshape(len(a), -1, 4), q[0].reshape(-1, 4)) < 0, -1.0, 1.0)
    qm = (q * sign.reshape(q.shape[:-1])[..., None]).sum(0)
    out[..., 3:7] = qm / np.linalg.norm(qm, axis=-1, keepdims=True)
    out[..., 7] = (a[..., 7].mean(0) >= 0.5).astype(float)
    return out


def knn_blend(source, neighbours: list[tuple[np.ndarray, np.ndarray, bool]], query_object_poses: np.ndarray) -> np.ndarray:
    """neighbours: [(actions, keypoints, mirrored)], nearest first -> the blended trajectory (L, 2, 8)."""
    if not neighbours:
        raise ValueError("knn_blend needs at least one neighbour")
    same = [nb for nb in neighbours if bool(nb[2]) == bool(neighbours[0][2])]
    return average_trajectories([carry_episode(source, a, k, m, query_object_poses) for a, k, m in same])


__all__ = ["carry_episode", "average_trajectories", "knn_blend"]
