"""How an episode is built from the demonstration: a :class:`Plan` of runs (each step follows an
object's transform or blends between two), the object-following and the thesis's schedules, and its
execution for a batch of transforms."""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.trajectories.segmentation import Segment
from demoforge.lib.trajectories.augmentation.source import estimate_object_poses, object_groups


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
