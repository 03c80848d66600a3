"""The mirror flip across the YZ plane (x = 0) of keypoints: reflected and re-ordered so each keeps its name
(the whole demonstration's flip, arms swapped, is :func:`demoforge.lib.trajectories.augmentation.source.mirror_source`)."""

from __future__ import annotations

import numpy as np

from demoforge.lib import geometry as geo


def mirror_permutation(keypoints_local: np.ndarray, keypoint_object: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """perm with keypoints_local[perm[i]] = M keypoints_local[i] (M: x -> -x) within the same object.

    A keypoint without a mirror partner maps to itself (only exact if it lies on the local x = 0 plane)."""
    kl = np.asarray(keypoints_local, float)
    ko = np.asarray(keypoint_object, int)
    m = kl * np.array([-1.0, 1.0, 1.0])
    d = np.linalg.norm(m[:, None, :] - kl[None, :, :], axis=-1) + np.where(ko[:, None] == ko[None, :], 0.0, np.inf)
    j = np.argmin(d, axis=1)
    ok = d[np.arange(len(kl)), j] <= tol
    return np.where(ok, j, np.arange(len(kl)))


def mirror_keypoints(keypoints: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """(..., K, 3) keypoints of a scene -> keypoints of its mirror image, in the same semantic order."""
    return geo.reflect_points(np.asarray(keypoints, float))[..., perm, :]
