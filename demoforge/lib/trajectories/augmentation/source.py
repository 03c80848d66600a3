"""The demonstration an augmentation starts from (:class:`DemoSource`: both arms' gripper trajectories,
segments, object keypoints in their objects' frames) and the object poses estimated from keypoints."""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.trajectories.segmentation import Segment
from demoforge.lib.trajectories.augmentation.mirror import mirror_permutation


# ============================================================================ demo source
@dataclass
class DemoSource:
    """A demonstration to augment (plain container, no task-library dependency)."""
    task: str
    trajectory: np.ndarray  # (T, 2, 8)
    keypoints: np.ndarray  # (K, 3) world, frame 0
    keypoint_object: np.ndarray  # (K,) object index per keypoint
    keypoints_local: np.ndarray  # (K, 3) in each object's frame
    segments: list  # Segment-like (arm, kind, start, end, object)
    object_arm: np.ndarray  # (n_objects,) arm handling each object
    mirrored: bool = False
    mirror_perm: np.ndarray | None = None  # (K,), default from keypoints_local
    workspace: np.ndarray | None = None  # (2, 3) xyz box the episodes must stay in (the task's); None: unbounded

    def __post_init__(self):
        self.trajectory = np.asarray(self.trajectory, float)
        self.keypoints = np.asarray(self.keypoints, float)
        self.keypoint_object = np.asarray(self.keypoint_object, int)
        self.keypoints_local = np.asarray(self.keypoints_local, float)
        self.object_arm = np.asarray(self.object_arm, int)
        if self.workspace is not None:
            self.workspace = np.asarray(self.workspace, float)
        self.segments = sorted((Segment(int(s.arm), str(s.kind), int(s.start), int(s.end), int(s.object))
                                for s in self.segments), key=lambda s: (s.arm, s.start))
        if self.mirror_perm is None:
            self.mirror_perm = mirror_permutation(self.keypoints_local, self.keypoint_object)
        if self.trajectory.ndim != 3 or self.trajectory.shape[1:] != (2, 8):
            raise ValueError(f"trajectory must be (T, 2, 8), got {self.trajectory.shape}")

    @property
    def n_frames(self) -> int:
        return self.trajectory.shape[0]

    @property
    def n_objects(self) -> int:
        return int(self.keypoint_object.max()) + 1

    def arm_segments(self, arm: int) -> list[Segment]:
        segs = [s for s in self.segments if s.arm == arm]
        if not segs:  # no labels: one motion segment
            segs = [Segment(arm, "motion", 0, self.n_frames, -1)]
        return segs


def from_scripted_demo(task, demo) -> DemoSource:
    """DemoSource from a task-library Task and one of its Demos (keypoints at frame 0)."""
    return DemoSource(task=task.name, trajectory=demo.gripper_actions(), keypoints=demo.keypoints()[0],
                      keypoint_object=task.keypoint_object, keypoints_local=task.keypoints_local,
                      segments=list(demo.segments), object_arm=task.object_arm(demo.mirror),
                      mirrored=bool(demo.mirror), workspace=task.workspace)


def mirror_source(src: DemoSource) -> DemoSource:
    """Reflect a demo across x = 0: poses (det +1), arms swapped, keypoints reflected + permuted."""
    traj = geo.reflect_pose8(src.trajectory[:, ::-1])
    kp = geo.reflect_points(src.keypoints)[src.mirror_perm]
    segs = [Segment(1 - s.arm, s.kind, s.start, s.end, s.object) for s in src.segments]
    return type(src)(task=src.task, trajectory=traj, keypoints=kp, keypoint_object=src.keypoint_object,
                     keypoints_local=src.keypoints_local, segments=segs, object_arm=1 - src.object_arm,
                     mirrored=not src.mirrored, mirror_perm=src.mirror_perm, workspace=src.workspace)


def estimate_object_poses(keypoints: np.ndarray, keypoints_local: np.ndarray,
                          keypoint_object: np.ndarray) -> np.ndarray:
    """(..., K, 3) world keypoints -> (..., n_objects, 4, 4) object poses by Kabsch (Umeyama, no scale)
    of the object's local keypoints onto the observed ones.

    Keypoints on one line (the whisk) fix only the line's direction: the twist about it is chosen so
    that a local axis perpendicular to the line is mapped to the horizontal direction z x line, which
    is exact for any yaw of an object whose pose keeps that axis horizontal (a whisk lying on the table).
    A single keypoint gives translation only (R = I)."""
    kp = np.asarray(keypoints, float)
    ko = np.asarray(keypoint_object, int)
    n_obj = int(ko.max()) + 1
    out = np.zeros(kp.shape[:-2] + (n_obj, 4, 4))
    out[..., :, 3, 3] = 1.0
    for o in range(n_obj):  # loop over objects (2), vectorised over the batch
        sel = ko == o
        src, dst = keypoints_local[sel], kp[..., sel, :]
        c = src - src.mean(0)
        sv = np.linalg.svd(c, compute_uv=False) if len(c) >= 2 else np.zeros(1)
        if len(c) >= 3 and sv.size >= 2 and sv[1] > 1e-6 * max(sv[0], 1e-12):
            _, R, t = geo.umeyama(np.broadcast_to(src, dst.shape), dst, with_scale=False)
        elif len(c) >= 2 and sv[0] > 1e-9:
            R = _line_rotation(c, dst - dst.mean(-2, keepdims=True))
            t = dst.mean(-2) - np.einsum("...ij,j->...i", R, src.mean(0))
        else:
            R = np.broadcast_to(np.eye(3), kp.shape[:-2] + (3, 3))
            t = dst.mean(-2) - src.mean(0)
        out[..., o, :3, :3] = R
        out[..., o, :3, 3] = t
    return out


def _line_rotation(src_c: np.ndarray, dst_c: np.ndarray) -> np.ndarray:
    """Rotation taking collinear local points (centred, (P, 3)) onto observed ones ((..., P, 3))."""
    u_local = np.linalg.svd(src_c)[2][0]
    s = src_c @ u_local                                   # (P,) positions along the line
    a = np.einsum("...pi,p->...i", dst_c, s)              # observed direction, same orientation
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    e = np.eye(3)[np.argmin(np.abs(u_local))]             # the local axis most perpendicular to the line
    v_local = e - (e @ u_local) * u_local
    v_local /= np.linalg.norm(v_local)
    v = np.cross(np.array([0.0, 0.0, 1.0]), a)
    vertical = np.linalg.norm(v, axis=-1, keepdims=True) < 1e-9
    v = np.where(vertical, np.cross(np.array([0.0, 1.0, 0.0]), a), v)   # line vertical: any horizontal
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    L = np.stack([v_local, np.cross(u_local, v_local), u_local], axis=-1)   # columns: local frame
    W = np.stack([v, np.cross(a, v), a], axis=-1)                          # columns: world frame
    return W @ L.T


def object_groups(src: DemoSource, stack_radius: float = 0.06) -> np.ndarray:
    """(n_objects,) group id: objects whose xy keypoint centroids are within stack_radius move together."""
    n = src.n_objects
    c = np.stack([src.keypoints[src.keypoint_object == o, :2].mean(0) for o in range(n)])
    g = np.arange(n)
    close = np.linalg.norm(c[:, None] - c[None], axis=-1) < stack_radius
    for i in range(n):  # tiny union-find over objects
        for j in range(i + 1, n):
            if close[i, j]:
                g[g == g[j]] = g[i]
    _, g = np.unique(g, return_inverse=True)
    return g
