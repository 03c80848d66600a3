"""Object-centric dual-arm demonstration augmentation (thesis 3.2) and mirror flipping (thesis 3.3).

One demonstration (gripper trajectory (T, 2, 8), object keypoints at frame 0 (11, 3), motion/skill
segments per arm) -> thousands of episodes in new scenes, vectorised over the whole batch.

Scene transform.  Every object o gets a rigid planar transform
    D_o = [Rz(dyaw), c_o + (dx, dy, 0) - Rz(dyaw) c_o]        (yaw about the pivot c_o, then shift)
so that the new object pose is T_o' = D_o T_o (thesis: T_obj' = T_move T_obj) and a gripper pose
re-projected through the object frame is T_o' T_o^-1 T_ee = D_o T_ee.  independent=False (the
thesis's setting): one (dx, dy, dyaw) for the whole scene, pivot = centroid of all keypoints, so
the whole scene moves rigidly.  independent=True: one (dx, dy, dyaw) per object *group*, pivot = the
group's keypoint centroid; objects whose initial xy centres are closer than `stack_radius` (a lid on
its container, flowers in their vase) form one group and move together.

Which transform a segment follows (Segment.object of the task library, DESIGN: "skill: the object
the hand acts on / relative to; motion: the object of the next skill"):
  * a skill segment follows its object exactly: T_new(t) = D_obj T_ee(t), so the gripper pose
    relative to that object is preserved (the pour follows the cup, which the other hand holds and
    which itself moves with D_cup; the holder's skill follows the cup too, so both agree);
  * mode "object" (default, ours): original timing is kept for both arms (so the arms stay as
    synchronised as in the human take, no waiting needed); a motion segment blends smoothly from
    the transform of where it starts (the previous skill's object; identity at frame 0, i.e. the
    robot's start pose is not moved) to the transform of where it ends (the next skill's object;
    identity for a final return-home segment), with a cubic ease e(u) = 3u^2 - 2u^3.  The blend of
    two planar transforms of the same pose is exact slerp/lerp: yaw and translation interpolated.
    With identity transforms this reproduces the original exactly.
  * mode "thesis": the thesis's schedule.  P0: cubic transition (n_transition frames) from the
    initial pose to the transformed start of the first motion segment; both arms wait for each
    other.  P1: first motion segment transformed (by its object's transform); the faster arm waits
    (holds its pose) until both are done.  P2: first skill segment transformed; wait.  P3: cubic
    transition from the end of the first skill back to the start of the second motion segment; P4:
    the rest of the original.  follow_objects=False (literal thesis): P4 is replayed in the world
    frame unchanged; follow_objects=True: P4 segments follow their objects as in mode "object".
    Caveat found on the six tasks: the receiving hand's first skill (grasp-hold-release) spans the
    other hand's whole task, so the P2 barrier makes the acting hand wait until the holder has
    released; the literal schedule is kept for comparison, "object" is the default.

Mirroring (thesis 3.3, task library base.py): points p -> M p (x -> -x); gripper poses by
lib.geometry.reflect_pose8 (reflect rows, negate the gripper y column: det +1, thumb stays thumb,
identical to the task library's P' = M P D); arms swapped; object keypoints reflected and permuted by
`mirror_permutation` (keypoint i of the mirrored scene = reflection of keypoint perm[i], perm swaps
the left/right pairs mirror-symmetric in the object's local x), which is exactly how the task library
builds its mirrored takes: the mirrored scripted demo of seed s is mirror_source(plain demo of seed s).

Episodes: the original demo is episode 0 (kind "original", identity transform), followed by
n - n_mirrored "translated" and n_mirrored "mirrored" (mirrored, then transformed) episodes, ids 0..n.
actions[i, :lengths[i]] is the full sequence including frame 0; initial = actions[:, 0].  Padding
(only when plans differ in length) repeats the final pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from lib import geometry as geo
from lib.segmentation import Segment

REJECT_REASONS = ("", "left_workspace", "grippers_too_close", "objects_overlap")


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

    def __post_init__(self):
        self.trajectory = np.asarray(self.trajectory, float)
        self.keypoints = np.asarray(self.keypoints, float)
        self.keypoint_object = np.asarray(self.keypoint_object, int)
        self.keypoints_local = np.asarray(self.keypoints_local, float)
        self.object_arm = np.asarray(self.object_arm, int)
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
                      mirrored=bool(demo.mirror))


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
    return DemoSource(task=src.task, trajectory=traj, keypoints=kp, keypoint_object=src.keypoint_object,
                      keypoints_local=src.keypoints_local, segments=segs, object_arm=1 - src.object_arm,
                      mirrored=not src.mirrored, mirror_perm=src.mirror_perm)


def mirror_keypoints(keypoints: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """(..., K, 3) keypoints of a scene -> keypoints of its mirror image, in the same semantic order."""
    return geo.reflect_points(np.asarray(keypoints, float))[..., perm, :]


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


# ============================================================================ plan (shared by all episodes)
@dataclass
class Run:
    """Output steps [out0, out0 + len(src_a)) of one arm: pose = blend(D_ka src_a, D_kb src_b, w).

    Transform index 0 = identity, 1 + o = object o's transform.  w None means w = 0 (pure A)."""
    arm: int
    out0: int
    src_a: np.ndarray
    ka: int
    src_b: np.ndarray | None = None
    kb: int = 0
    w: np.ndarray | None = None


@dataclass
class Plan:
    length: int
    runs: list[Run]
    src: np.ndarray  # (L, 2) main source frame per output step (for inspection / tests)
    inserted: np.ndarray  # (L, 2) bool: waiting or transition frames not in the original
    skill_object: np.ndarray  # (L, 2) object a step is rigidly relative to (-1: not a skill step)


def _ease(u: np.ndarray) -> np.ndarray:
    return u * u * (3.0 - 2.0 * u)


def _object_runs(arm: int, segs: list[Segment], lo: int, hi: int, out0: int, k_start: int, k_end: int,
                 T: int, follow: bool = True) -> list[Run]:
    """Runs for source frames [lo, hi) of one arm: skills follow their object, motions blend."""
    runs: list[Run] = []
    segs = [s for s in segs if s.end > lo and s.start < hi]
    if not follow:
        return [Run(arm, out0, np.arange(lo, hi), 0)]
    for i, s in enumerate(segs):
        a, b = max(s.start, lo), min(s.end, hi)
        frames = np.arange(a, b)
        o = out0 + a - lo
        if s.kind == "skill":
            runs.append(Run(arm, o, frames, 1 + s.object if s.object >= 0 else 0))
            continue
        prev = segs[i - 1] if i > 0 else None
        nxt = segs[i + 1] if i + 1 < len(segs) else None
        k0 = (1 + prev.object if prev.object >= 0 else 0) if prev is not None else k_start
        if nxt is not None:
            k1 = 1 + nxt.object if nxt.object >= 0 else 0
        else:
            k1 = k_end
        if k0 == k1:
            runs.append(Run(arm, o, frames, k0))
            continue
        left = a - 1 if a > 0 else 0  # frame with weight 0 (end of the previous segment / frame 0)
        right = b if b < T else T - 1  # frame with weight 1 (start of the next segment / last frame)
        u = np.clip((frames - left) / max(right - left, 1), 0.0, 1.0)
        runs.append(Run(arm, o, frames, k0, frames, k1, _ease(u)))
    return runs


def plan_object(src: DemoSource) -> Plan:
    T = src.n_frames
    runs = []
    for arm in range(2):
        runs += _object_runs(arm, src.arm_segments(arm), 0, T, 0, 0, 0, T)
    return _finish_plan(T, runs, src)


def plan_thesis(src: DemoSource, n_transition: int = 15, follow_objects: bool = False) -> Plan:
    T = src.n_frames
    parts = []
    for arm in range(2):
        segs = src.arm_segments(arm)
        i = 0
        m1 = segs[0] if segs[0].kind == "motion" else Segment(arm, "motion", 0, 0, segs[0].object)
        if segs[0].kind == "motion":
            i = 1
        s1 = segs[i] if i < len(segs) and segs[i].kind == "skill" else Segment(arm, "skill", m1.end, m1.end, m1.object)
        parts.append((segs, m1, s1))
    n1 = max(p[1].end - p[1].start for p in parts)
    n2 = max(p[2].end - p[2].start for p in parts)
    n4 = max(T - p[2].end for p in parts)
    L = n_transition + n1 + n2 + n_transition + n4
    runs: list[Run] = []
    e = _ease(np.linspace(0.0, 1.0, n_transition)) if n_transition >= 2 else np.ones(n_transition)
    for arm, (segs, m1, s1) in enumerate(parts):
        k1 = 1 + m1.object if m1.object >= 0 else 0
        ks = 1 + s1.object if s1.object >= 0 else 0
        first = m1.start if m1.end > m1.start else s1.start
        last = min(max(s1.end, m1.end, 1), T) - 1  # last frame of the first phase
        rest = min(last + 1, T - 1)
        nxt = [s for s in segs if s.start >= s1.end]
        k4 = (1 + nxt[0].object if nxt and nxt[0].object >= 0 else 0) if follow_objects else 0
        k_last = ks if s1.end > s1.start else k1
        pos = 0
        if n_transition:
            runs.append(Run(arm, pos, np.zeros(n_transition, int), 0, np.full(n_transition, first), k1, e))
        pos += n_transition
        for seg, k, n in ((m1, k1, n1), (s1, ks, n2)):
            fr = np.arange(seg.start, seg.end)
            if len(fr):
                runs.append(Run(arm, pos, fr, k))
            hold = seg.end - 1 if len(fr) else (runs[-1].src_b[-1] if runs[-1].src_b is not None else runs[-1].src_a[-1])
            kh = k if len(fr) else (runs[-1].kb if runs[-1].w is not None else runs[-1].ka)
            if n - len(fr) > 0:
                runs.append(Run(arm, pos + len(fr), np.full(n - len(fr), hold), kh))
            pos += n
        if n_transition:
            runs.append(Run(arm, pos, np.full(n_transition, last), k_last, np.full(n_transition, rest), k4, e))
        pos += n_transition
        if s1.end < T:
            runs += _object_runs(arm, segs, s1.end, T, pos, k4, 0, T, follow=follow_objects)
        pad = n4 - (T - s1.end)
        if pad > 0:
            runs.append(Run(arm, pos + T - s1.end, np.full(pad, T - 1), 0))
    return _finish_plan(L, runs, src)


def _finish_plan(L: int, runs: list[Run], src: DemoSource) -> Plan:
    srcmap = np.full((L, 2), -1)
    inserted = np.zeros((L, 2), bool)
    skill_obj = np.full((L, 2), -1)
    seg_obj = np.full((src.n_frames, 2), -1)
    for s in src.segments:
        if s.kind == "skill":
            seg_obj[s.start:s.end, s.arm] = s.object
    for r in runs:
        sl = slice(r.out0, r.out0 + len(r.src_a))
        main = r.src_a if r.w is None else np.where(r.w < 0.5, r.src_a, r.src_b)
        srcmap[sl, r.arm] = main
        same = r.src_b is None or np.array_equal(r.src_a, r.src_b)
        consec = len(r.src_a) > 0 and np.all(np.diff(r.src_a) == 1)
        if not (same and (consec or len(r.src_a) == 1)):
            inserted[sl, r.arm] = True
        if r.w is None and r.ka >= 1:
            skill_obj[sl, r.arm] = np.where(seg_obj[r.src_a, r.arm] == r.ka - 1, r.ka - 1, -1)
    # frames repeated by waiting: a source frame used more than once is inserted after its first use
    for arm in range(2):
        s = srcmap[:, arm]
        rep = np.zeros(L, bool)
        rep[1:] = s[1:] == s[:-1]
        inserted[:, arm] |= rep
    if np.any(srcmap < 0):
        raise RuntimeError("plan does not cover every output step")
    return Plan(L, runs, srcmap, inserted, skill_obj)


def make_plan(src: DemoSource, mode: str = "object", n_transition: int = 15, follow_objects: bool = False) -> Plan:
    if mode == "object":
        return plan_object(src)
    if mode == "thesis":
        return plan_thesis(src, n_transition, follow_objects)
    raise ValueError(f"mode must be 'object' or 'thesis', got {mode!r}")


# ============================================================================ transforms
def _pivots(src: DemoSource, independent: bool, stack_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(n_objects,) group per object and (n_objects, 2) xy pivot per object."""
    n = src.n_objects
    if not independent:
        return np.zeros(n, int), np.broadcast_to(src.keypoints[:, :2].mean(0), (n, 2)).copy()
    g = object_groups(src, stack_radius)
    piv = np.stack([src.keypoints[np.isin(src.keypoint_object, np.flatnonzero(g == g[o])), :2].mean(0)
                    for o in range(n)])
    return g, piv


def transform_tables(params: np.ndarray, pivots: np.ndarray) -> tuple[np.ndarray, ...]:
    """params (N, n_obj, 3) [dx, dy, dyaw], pivots (N or 1, n_obj, 2) -> per transform index k
    (0 = identity, 1 + o) the tables yaw, tx, ty of shape (N, 1 + n_obj)."""
    N = params.shape[0]
    yaw = np.concatenate([np.zeros((N, 1)), params[..., 2]], axis=1)
    c, s = np.cos(params[..., 2]), np.sin(params[..., 2])
    px, py = pivots[..., 0], pivots[..., 1]
    tx = np.concatenate([np.zeros((N, 1)), px + params[..., 0] - (c * px - s * py)], axis=1)
    ty = np.concatenate([np.zeros((N, 1)), py + params[..., 1] - (s * px + c * py)], axis=1)
    return yaw, tx, ty


def transform_matrices(params: np.ndarray, pivots: np.ndarray) -> np.ndarray:
    """(N, n_obj, 3) params -> (N, n_obj, 4, 4) D_o (new object pose = D_o @ old)."""
    yaw, tx, ty = transform_tables(params, pivots)
    D = np.zeros(params.shape[:2] + (4, 4))
    D[..., :3, :3] = geo.yaw_rotation(params[..., 2])
    D[..., 0, 3], D[..., 1, 3] = tx[:, 1:], ty[:, 1:]
    D[..., 3, 3] = 1.0
    return D


def _apply_planar(traj: np.ndarray, frames: np.ndarray, yaw: np.ndarray, tx: np.ndarray, ty: np.ndarray,
                  out: np.ndarray) -> None:
    """out (N, m, 8) = planar transform (yaw, tx, ty: (N,)) of traj[frames] (m, 8) (one arm)."""
    p = traj[frames]
    if out.shape[-1] == 3:  # positions only (validation)
        p = p[:, :3]
    if not np.any(yaw):  # translation only (the thesis's augmentation): 3 passes
        out[...] = p
        out[..., 0] += tx[:, None]
        out[..., 1] += ty[:, None]
        return
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    ch, sh = np.cos(0.5 * yaw)[:, None], np.sin(0.5 * yaw)[:, None]
    x, y = p[:, 0], p[:, 1]
    out[..., 0] = c * x - s * y + tx[:, None]
    out[..., 1] = s * x + c * y + ty[:, None]
    out[..., 2] = p[:, 2]
    if out.shape[-1] == 3:
        return
    qx, qy, qz, qw = p[:, 3], p[:, 4], p[:, 5], p[:, 6]
    # q' = [0, 0, sin(yaw/2), cos(yaw/2)] * q  (scalar-last)
    out[..., 3] = ch * qx - sh * qy
    out[..., 4] = ch * qy + sh * qx
    out[..., 5] = ch * qz + sh * qw
    out[..., 6] = ch * qw - sh * qz
    out[..., 7] = p[:, 7]


def execute_plan(src: DemoSource, plan: Plan, params: np.ndarray, pivots: np.ndarray,
                 out: np.ndarray | None = None) -> np.ndarray:
    """Actions (N, L, 2, 8) of the N scenes params (N, n_obj, 3) under one plan (vectorised over N;
    pivots (N or 1, n_obj, 2)).  Writes into `out` if given (any float dtype)."""
    N = params.shape[0]
    yaw, tx, ty = transform_tables(params, pivots)
    if out is None:
        out = np.empty((N, plan.length, 2, 8))
    traj = src.trajectory
    for r in plan.runs:  # a handful of runs per arm, each vectorised over (episodes x steps)
        m = len(r.src_a)
        if m == 0:
            continue
        dst = out[:, r.out0:r.out0 + m, r.arm, :]
        if r.w is None:
            _apply_planar(traj[:, r.arm], r.src_a, yaw[:, r.ka], tx[:, r.ka], ty[:, r.ka], dst)
            continue
        w = r.w[None, :]
        if np.array_equal(r.src_a, r.src_b):
            # the same source pose under two planar transforms: slerp = yaw interpolation, lerp positions
            p = traj[r.src_a, r.arm]
            ax, ay = _apply_xy(p, yaw[:, r.ka], tx[:, r.ka], ty[:, r.ka])
            bx, by = _apply_xy(p, yaw[:, r.kb], tx[:, r.kb], ty[:, r.kb])
            dyaw = np.angle(np.exp(1j * (yaw[:, r.kb] - yaw[:, r.ka])))[:, None]
            half = 0.5 * (yaw[:, r.ka][:, None] + w * dyaw)
            ch, sh = np.cos(half), np.sin(half)
            dst[..., 0] = ax + w * (bx - ax)
            dst[..., 1] = ay + w * (by - ay)
            dst[..., 2] = p[:, 2]
            if dst.shape[-1] == 3:
                continue
            dst[..., 3] = ch * p[:, 3] - sh * p[:, 4]
            dst[..., 4] = ch * p[:, 4] + sh * p[:, 3]
            dst[..., 5] = ch * p[:, 5] + sh * p[:, 6]
            dst[..., 6] = ch * p[:, 6] - sh * p[:, 5]
            dst[..., 7] = p[:, 7]
        else:
            if dst.shape[-1] == 3:
                A, B = np.empty((N, m, 3)), np.empty((N, m, 3))
                _apply_planar(traj[:, r.arm], r.src_a, yaw[:, r.ka], tx[:, r.ka], ty[:, r.ka], A)
                _apply_planar(traj[:, r.arm], r.src_b, yaw[:, r.kb], tx[:, r.kb], ty[:, r.kb], B)
                dst[...] = A + w[..., None] * (B - A)
                continue
            A = np.empty((N, m, 8))
            B = np.empty((N, m, 8))
            _apply_planar(traj[:, r.arm], r.src_a, yaw[:, r.ka], tx[:, r.ka], ty[:, r.ka], A)
            _apply_planar(traj[:, r.arm], r.src_b, yaw[:, r.kb], tx[:, r.kb], ty[:, r.kb], B)
            dst[..., :3] = A[..., :3] + w[..., None] * (B[..., :3] - A[..., :3])
            dst[..., 3:7] = geo.quat_slerp(A[..., 3:7], B[..., 3:7], np.broadcast_to(w, (N, m)))
            dst[..., 7] = np.where(w < 1.0, A[..., 7], B[..., 7])
    return out


def _apply_xy(p: np.ndarray, yaw: np.ndarray, tx: np.ndarray, ty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return c * p[:, 0] - s * p[:, 1] + tx[:, None], s * p[:, 0] + c * p[:, 1] + ty[:, None]


def transform_keypoints(src: DemoSource, params: np.ndarray, pivots: np.ndarray) -> np.ndarray:
    """(N, K, 3) keypoints of the N new scenes."""
    yaw, tx, ty = transform_tables(params, pivots)
    k = 1 + src.keypoint_object
    c, s = np.cos(yaw[:, k]), np.sin(yaw[:, k])
    x, y = src.keypoints[:, 0], src.keypoints[:, 1]
    out = np.empty((params.shape[0],) + src.keypoints.shape)
    out[..., 0] = c * x - s * y + tx[:, k]
    out[..., 1] = s * x + c * y + ty[:, k]
    out[..., 2] = src.keypoints[:, 2]
    return out


def transform_demo(source: DemoSource, object_poses_new: np.ndarray, mode: str = "object",
                   n_transition: int = 15, follow_objects: bool = False) -> np.ndarray:
    """The demo re-targeted to one new scene: object_poses_new (n_obj, 4, 4) world poses of the objects
    (e.g. estimated from the new scene's keypoints with estimate_object_poses).  The change of each
    object's pose D_o = T_o' T_o^-1 is projected to a planar transform (yaw about z + xy shift; the
    scheme's augmentation space).  Returns actions (L, 2, 8)."""
    P0 = estimate_object_poses(source.keypoints, source.keypoints_local, source.keypoint_object)
    D = np.asarray(object_poses_new, float) @ geo.transform_inverse(P0)
    yaw = np.arctan2(D[:, 1, 0], D[:, 0, 0])
    params = np.stack([D[:, 0, 3], D[:, 1, 3], yaw], axis=-1)[None]  # pivot 0: D is about the origin
    plan = make_plan(source, mode, n_transition, follow_objects)
    return execute_plan(source, plan, params, np.zeros((1, source.n_objects, 2)))[0]


# ============================================================================ episode generation
_CHUNK = 256  # episodes per chunk: a chunk's actions (~10 MB) stay cache/page friendly


@dataclass
class _Group:
    """Rows [row0, row1) of a batch generated from one source under one plan."""
    src: DemoSource
    plan: Plan
    row0: int
    row1: int


@dataclass
class EpisodeBatch:
    """Episodes of one task.  actions are materialised lazily on first access of .actions (the
    parameters, keypoints and validity are computed eagerly); episode_actions(ids) computes a few."""
    task: str
    episode_id: np.ndarray  # (N,) int64, 0 = the original demo
    kind: np.ndarray  # (N,) str: original | translated | mirrored
    params: np.ndarray  # (N, n_obj, 3) [dx, dy, dyaw] per object (same for all objects if not independent)
    pivots: np.ndarray  # (N, n_obj, 2) xy pivot of each object's yaw
    keypoints: np.ndarray  # (N, K, 3) object keypoints at the start
    initial: np.ndarray  # (N, 2, 8) initial gripper poses (= actions[:, 0])
    lengths: np.ndarray  # (N,)
    valid: np.ndarray  # (N,) bool
    reject_reason: np.ndarray  # (N,) str
    min_gripper_distance: np.ndarray  # (N,)
    n_steps_max: int
    groups: list = field(default_factory=list, repr=False)
    dtype: object = np.float64
    _actions: np.ndarray | None = field(default=None, repr=False)

    @property
    def mirrored(self) -> np.ndarray:
        return self.kind == "mirrored"

    def __len__(self) -> int:
        return len(self.episode_id)

    def reason_counts(self) -> dict[str, int]:
        r, c = np.unique(self.reject_reason, return_counts=True)
        return {str(a): int(b) for a, b in zip(r, c)}

    @property
    def actions(self) -> np.ndarray:
        """(N, n_steps_max, 2, 8), padded by repeating the final pose (see lengths)."""
        if self._actions is None:
            out = np.empty((len(self), self.n_steps_max, 2, 8), dtype=self.dtype)
            _for_chunks(self, lambda g, a, b, buf: None, out=out)
            self._actions = out
        return self._actions

    def episode_actions(self, ids) -> np.ndarray:
        """(k, n_steps_max, 2, 8) actions of the episodes ids (positions in this batch)."""
        ids = np.atleast_1d(np.asarray(ids, int))
        out = np.empty((len(ids), self.n_steps_max, 2, 8), dtype=self.dtype)
        for g in self.groups:
            sel = (ids >= g.row0) & (ids < g.row1)
            if sel.any():
                _fill(g, self.params[ids[sel]], self.pivots[ids[sel]][:1], out, np.flatnonzero(sel))
        return out


def _truncate_plan(plan: Plan, n: int) -> Plan:
    """The first n output steps of a plan."""
    runs = []
    for r in plan.runs:
        k = min(len(r.src_a), n - r.out0)
        if k > 0:
            runs.append(Run(r.arm, r.out0, r.src_a[:k], r.ka, None if r.src_b is None else r.src_b[:k], r.kb,
                            None if r.w is None else r.w[:k]))
    return Plan(n, runs, plan.src[:n], plan.inserted[:n], plan.skill_object[:n])


def _fill(g: _Group, params: np.ndarray, pivots: np.ndarray, out: np.ndarray, rows) -> None:
    L = g.plan.length
    if isinstance(rows, slice):
        execute_plan(g.src, g.plan, params, pivots, out=out[rows, :L])
        if L < out.shape[1]:
            out[rows, L:] = out[rows, L - 1:L]
    else:
        tmp = execute_plan(g.src, g.plan, params, pivots)
        out[rows, :L] = tmp
        out[rows, L:] = tmp[:, -1:]


def _for_chunks(batch: EpisodeBatch, fn, out: np.ndarray | None = None, workers: int = 2) -> None:
    """Compute the actions chunk by chunk (2 threads; numpy releases the GIL) and call
    fn(group, row0, row1, actions_chunk) on each; into `out` if given, else into a reused buffer."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    tasks = [(g, a, min(a + _CHUNK, g.row1)) for g in batch.groups for a in range(g.row0, g.row1, _CHUNK)]
    local = threading.local()

    def work(t):
        g, a, b = t
        if out is not None:
            dst, rows = out, slice(a, b)
        else:
            buf = getattr(local, "buf", None)
            if buf is None:  # validation only needs positions: 3 channels
                buf = local.buf = np.empty((_CHUNK, batch.n_steps_max, 2, 3))
            dst, rows = buf, slice(0, b - a)
        _fill(g, batch.params[a:b], batch.pivots[a:a + 1], dst, rows)
        fn(g, a, b, dst[rows])

    if workers <= 1 or len(tasks) <= 1:
        for t in tasks:
            work(t)
    else:
        with ThreadPoolExecutor(workers) as ex:
            list(ex.map(work, tasks))


def sample_params(rng: np.random.Generator, n: int, n_objects: int, groups: np.ndarray,
                  translation_range, yaw_range) -> np.ndarray:
    """(n, n_objects, 3) uniform [dx, dy, dyaw], one draw per group."""
    ng = int(groups.max()) + 1
    (x0, x1), (y0, y1) = translation_range
    lo = np.array([x0, y0, yaw_range[0]])
    hi = np.array([x1, y1, yaw_range[1]])
    g = rng.uniform(lo, hi, size=(n, ng, 3))
    return g[:, groups, :]


def check_episodes(actions: np.ndarray, keypoints: np.ndarray, lengths: np.ndarray, workspace: np.ndarray,
                   safety_distance: float, keypoint_object: np.ndarray | None = None,
                   groups: np.ndarray | None = None, min_object_distance: float = 0.0):
    """Validity per episode: (valid (N,), reason (N,) str, min gripper distance (N,)).  Order of
    reasons: left_workspace (a gripper position or a keypoint outside the xyz box), grippers_too_close
    (the two gripper positions closer than safety_distance at some step), objects_overlap (xy centroids
    of objects in different groups closer than min_object_distance)."""
    N, L = actions.shape[:2]
    lo, hi = np.asarray(workspace, float)
    lengths = np.asarray(lengths)
    pos = actions[..., :3]
    if np.all(lengths == L):
        mn, mx = pos.min(axis=(1, 2)), pos.max(axis=(1, 2))
    else:
        step_ok = (np.arange(L)[None, :] < lengths[:, None])[..., None, None]
        mn = np.where(step_ok, pos, np.inf).min(axis=(1, 2))
        mx = np.where(step_ok, pos, -np.inf).max(axis=(1, 2))
    out_ws = np.any((mn < lo) | (mx > hi), axis=-1) | np.any((keypoints < lo) | (keypoints > hi), axis=(-1, -2))
    diff = pos[:, :, 0] - pos[:, :, 1]
    d2 = np.einsum("nlc,nlc->nl", diff, diff)
    if not np.all(lengths == L):
        d2 = np.where(np.arange(L)[None, :] < lengths[:, None], d2, np.inf)
    dmin = np.sqrt(d2.min(1))
    close = dmin < safety_distance
    overlap = np.zeros(N, bool)
    if keypoint_object is not None and groups is not None and min_object_distance > 0:
        n_obj = int(keypoint_object.max()) + 1
        c = np.stack([keypoints[:, keypoint_object == o, :2].mean(1) for o in range(n_obj)], axis=1)
        dd = np.linalg.norm(c[:, :, None] - c[:, None], axis=-1)
        diff = groups[:, None] != groups[None, :]
        overlap = np.any((dd < min_object_distance) & diff[None], axis=(1, 2))
    reason = np.full(N, "", dtype=object)
    reason[overlap] = "objects_overlap"
    reason[close] = "grippers_too_close"
    reason[out_ws] = "left_workspace"
    return reason == "", reason.astype(str), dmin


def generate_episodes(demo_source: DemoSource, n: int = 10_000, n_mirrored: int = 5_000, seed: int = 0,
                      workspace=None, translation_range=((-0.15, 0.15), (-0.12, 0.12)), yaw_range=(0.0, 0.0),
                      independent: bool = False, safety_distance: float = 0.04, mode: str = "object",
                      n_transition: int = 15, follow_objects: bool = False, stack_radius: float = 0.06,
                      min_object_distance: float = 0.1, dtype=np.float64, materialize: bool = False,
                      workers: int = 2) -> EpisodeBatch:
    """Original (episode 0) + n augmented episodes: n - n_mirrored translated, n_mirrored mirrored and
    translated, each uniform in translation_range ((dx0, dx1), (dy0, dy1)) metres and yaw_range radians
    (one draw for the whole scene, or per object group if independent).  workspace: (2, 3) xyz box
    (default: the task library's box of the task, if known; else unbounded).  Validity is computed for
    every episode; actions are materialised now if materialize, else on first access of .actions."""
    src = demo_source
    if workspace is None:
        try:
            from lib.task_library import get_task
            workspace = get_task(src.task).workspace
        except Exception:
            workspace = np.array([[-np.inf] * 3, [np.inf] * 3])
    workspace = np.asarray(workspace, float)
    if not 0 <= n_mirrored <= n:
        raise ValueError(f"need 0 <= n_mirrored <= n, got n={n}, n_mirrored={n_mirrored}")
    rng = np.random.default_rng(seed)
    n_plain = n - n_mirrored
    msrc = mirror_source(src)
    groups, piv = _pivots(src, independent, stack_radius)
    _, piv_m = _pivots(msrc, independent, stack_radius)
    n_obj = src.n_objects
    p_plain = sample_params(rng, n_plain, n_obj, groups, translation_range, yaw_range)
    p_mirr = sample_params(rng, n_mirrored, n_obj, groups, translation_range, yaw_range)
    plan = make_plan(src, mode, n_transition, follow_objects)
    plan_m = make_plan(msrc, mode, n_transition, follow_objects)
    L = max(plan.length, plan_m.length)
    N = 1 + n
    params = np.concatenate([np.zeros((1, n_obj, 3)), p_plain, p_mirr])
    pivots = np.concatenate([np.broadcast_to(piv, (1 + n_plain, n_obj, 2)),
                             np.broadcast_to(piv_m, (n_mirrored, n_obj, 2))])
    lengths = np.concatenate([np.full(1 + n_plain, plan.length), np.full(n_mirrored, plan_m.length)])
    kp = np.concatenate([transform_keypoints(src, params[:1 + n_plain], pivots[:1]),
                         transform_keypoints(msrc, p_mirr, pivots[1 + n_plain:][:1])])
    kind = np.array(["original"] + ["translated"] * n_plain + ["mirrored"] * n_mirrored)
    grp = [g for g in (_Group(src, plan, 0, 1 + n_plain), _Group(msrc, plan_m, 1 + n_plain, N)) if g.row1 > g.row0]
    batch = EpisodeBatch(task=src.task, episode_id=np.arange(N, dtype=np.int64), kind=kind, params=params,
                         pivots=pivots, keypoints=kp, initial=np.empty((N, 2, 8)), lengths=lengths,
                         valid=np.empty(N, bool), reject_reason=np.empty(N, dtype="<U20"),
                         min_gripper_distance=np.empty(N), n_steps_max=L, groups=grp, dtype=dtype)

    def check(g, a, b, acts):
        v, r, d = check_episodes(acts, kp[a:b], lengths[a:b], workspace, safety_distance, src.keypoint_object,
                                 groups if independent else None, min_object_distance)
        batch.valid[a:b], batch.reject_reason[a:b], batch.min_gripper_distance[a:b] = v, r, d

    out = np.empty((N, L, 2, 8), dtype=dtype) if materialize else None
    _for_chunks(batch, check, out=out, workers=workers)
    batch._actions = out
    for g in grp:  # initial gripper poses: the first output step of each plan
        execute_plan(g.src, _truncate_plan(g.plan, 1), params[g.row0:g.row1], pivots[g.row0:g.row0 + 1],
                     out=batch.initial[g.row0:g.row1, None])
    return batch


# ============================================================================ reference loop (baseline)
def transform_demo_loop(src: DemoSource, plan: Plan, params_one: np.ndarray, pivots_one: np.ndarray) -> np.ndarray:
    """Per-step, per-arm Python loop with 4x4 matrices: the straightforward reference (baseline/tests)."""
    D = [np.eye(4)] + list(transform_matrices(params_one[None], pivots_one[None])[0])
    out = np.zeros((plan.length, 2, 8))
    for r in plan.runs:
        for j in range(len(r.src_a)):
            Ta, ga = geo.pose8_to_transform(src.trajectory[r.src_a[j], r.arm])
            A = D[r.ka] @ Ta
            if r.w is None:
                out[r.out0 + j, r.arm] = geo.transform_to_pose8(A, ga)
                continue
            Tb, gb = geo.pose8_to_transform(src.trajectory[r.src_b[j], r.arm])
            B = D[r.kb] @ Tb
            w = r.w[j]
            qa, qb = geo.matrix_to_quat(A[:3, :3]), geo.matrix_to_quat(B[:3, :3])
            p = (1 - w) * A[:3, 3] + w * B[:3, 3]
            q = geo.quat_slerp(qa, qb, w)
            out[r.out0 + j, r.arm] = np.concatenate([p, q, [ga if w < 1.0 else gb]])
    return out


__all__ = ["DemoSource", "Segment", "from_scripted_demo", "mirror_permutation", "mirror_source",
           "mirror_keypoints", "estimate_object_poses", "object_groups", "Plan", "Run", "make_plan",
           "plan_object", "plan_thesis", "transform_tables", "transform_matrices", "execute_plan",
           "transform_keypoints", "transform_demo", "EpisodeBatch", "sample_params", "check_episodes",
           "generate_episodes", "transform_demo_loop", "REJECT_REASONS"]
