"""The mirror flip across the YZ plane (x = 0): the arms' roles swapped, keypoints reflected and
re-ordered so each keeps its name."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.trajectories.segmentation import Segment
if TYPE_CHECKING:  # source.py needs mirror_permutation at run time
    from demoforge.lib.trajectories.augmentation.source import DemoSource


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


def mirror_source(src: DemoSource) -> DemoSource:
    """Reflect a demo across x = 0: poses (det +1), arms swapped, keypoints reflected + permuted."""
    traj = geo.reflect_pose8(src.trajectory[:, ::-1])
    kp = geo.reflect_points(src.keypoints)[src.mirror_perm]
    segs = [Segment(1 - s.arm, s.kind, s.start, s.end, s.object) for s in src.segments]
    return type(src)(task=src.task, trajectory=traj, keypoints=kp, keypoint_object=src.keypoint_object,
                     keypoints_local=src.keypoints_local, segments=segs, object_arm=1 - src.object_arm,
                     mirrored=not src.mirrored, mirror_perm=src.mirror_perm)


def mirror_keypoints(keypoints: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """(..., K, 3) keypoints of a scene -> keypoints of its mirror image, in the same semantic order."""
    return geo.reflect_points(np.asarray(keypoints, float))[..., perm, :]
