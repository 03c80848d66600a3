"""Query scenes outside the augmented data: placements shifted beyond the augmentation's translation
box, and the test of whether a scene lies inside it.

The augmented database moves the original placement (or its mirror image) by translations drawn
from a box [dx0, dx1] x [dy0, dy1]; a scene whose objects all sit inside that box around the
original is "in the augmented region".  Out-of-distribution scenes move the whole original
placement by an offset outside the box, kept on the workspace so the robot can still reach them.
"""

from __future__ import annotations

import numpy as np

MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])  # x -> -x, the mirror plane of docs/architecture.md


def translation_box(transforms: np.ndarray) -> np.ndarray:
    """(N, n_obj, 3) sampled [dx, dy, dyaw] of augmented episodes -> (2, 2) [[dx0, dy0], [dx1, dy1]]."""
    t = np.asarray(transforms, float)[..., :2].reshape(-1, 2)
    if len(t) == 0:
        raise ValueError("no augmented episodes: the translation box is unknown")
    return np.stack([t.min(0), t.max(0)])


def placement_offsets(original_poses: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """(n_obj, 2) xy offsets of each object from its original placement."""
    return np.asarray(poses)[:, :2, 3] - np.asarray(original_poses)[:, :2, 3]


def in_box(offsets: np.ndarray, box: np.ndarray, tol: float = 1e-6) -> bool:
    """Every object's offset lies inside the (2, 2) box."""
    off = np.asarray(offsets, float)
    return bool(np.all((off >= box[0] - tol) & (off <= box[1] + tol)))


def ood_placement(original_poses: np.ndarray, box: np.ndarray, rng: np.random.Generator, keypoints_fn,
                  workspace: np.ndarray, scale: float = 1.8, margin: float = 1.15, tries: int = 10_000) -> np.ndarray:
    """The original placement moved as a whole by an xy offset drawn uniformly from the box grown by
    ``scale`` about its centre, minus the box grown by ``margin`` (clearly outside what was sampled),
    such that every keypoint (``keypoints_fn(poses) -> (k, 3)``) stays inside the workspace's xy."""
    box = np.asarray(box, float)
    centre, half = box.mean(0), (box[1] - box[0]) / 2
    lo, hi = centre - scale * half, centre + scale * half
    inner_lo, inner_hi = centre - margin * half, centre + margin * half
    ws = np.asarray(workspace, float)
    for _ in range(tries):
        d = rng.uniform(lo, hi)
        if np.all((d > inner_lo) & (d < inner_hi)):
            continue
        poses = np.array(original_poses, float)
        poses[:, :2, 3] += d
        kp = keypoints_fn(poses)
        if np.all((kp[:, :2] >= ws[0, :2]) & (kp[:, :2] <= ws[1, :2])):
            return poses
    raise ValueError(f"no out-of-distribution placement inside the workspace {ws[:, :2].tolist()} in {tries} "
                     f"draws around the box {box.tolist()}: lower `scale` or widen the workspace")
