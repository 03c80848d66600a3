"""Generating the episode database: transforms sampled, episodes built in chunks over threads, and each
checked (workspace, grippers too close, objects overlapping)."""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.trajectories.segmentation import Segment
from demoforge.lib.trajectories.augmentation.source import DemoSource, mirror_source
from demoforge.lib.trajectories.augmentation.plan import (
    Plan, Run, _pivots, execute_plan, make_plan, transform_keypoints, transform_matrices,
)


REJECT_REASONS = ("", "left_workspace", "grippers_too_close", "objects_overlap")


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


def draw_placements(src: DemoSource, n: int, n_mirrored: int, rng: np.random.Generator,
                    translation_range=((-0.15, 0.15), (-0.12, 0.12)), yaw_range=(0.0, 0.0), independent: bool = False,
                    stack_radius: float = 0.06) -> np.ndarray:
    """(n, n_obj, 3) [dx, dy, dyaw] of n episodes, the n - n_mirrored plain ones first (generate_episodes'
    draw; the mirrored source's groups are the plain one's)."""
    groups, _ = _pivots(src, independent, stack_radius)
    return np.concatenate([sample_params(rng, n - n_mirrored, src.n_objects, groups, translation_range, yaw_range),
                           sample_params(rng, n_mirrored, src.n_objects, groups, translation_range, yaw_range)])


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
                      workers: int = 2, placements: np.ndarray | None = None) -> EpisodeBatch:
    """Original (episode 0) + n augmented episodes: n - n_mirrored translated, n_mirrored mirrored and
    translated, each uniform in translation_range ((dx0, dx1), (dy0, dy1)) metres and yaw_range radians
    (one draw for the whole scene, or per object group if independent).  workspace: (2, 3) xyz box
    (default: the source's, i.e. the task library's box of the task; else unbounded).  Validity is computed for
    every episode; actions are materialised now if materialize, else on first access of .actions.
    placements: (n, n_obj, 3) [dx, dy, dyaw] of episodes 1..n instead of the seed's draw (the plain ones
    first), e.g. some of them drawn again (servable.py)."""
    src = demo_source
    if workspace is None:
        workspace = src.workspace if src.workspace is not None else np.array([[-np.inf] * 3, [np.inf] * 3])
    workspace = np.asarray(workspace, float)
    if not 0 <= n_mirrored <= n:
        raise ValueError(f"need 0 <= n_mirrored <= n, got n={n}, n_mirrored={n_mirrored}")
    n_plain = n - n_mirrored
    msrc = mirror_source(src)
    groups, piv = _pivots(src, independent, stack_radius)
    _, piv_m = _pivots(msrc, independent, stack_radius)
    n_obj = src.n_objects
    if placements is None:
        placements = draw_placements(src, n, n_mirrored, np.random.default_rng(seed), translation_range, yaw_range,
                                     independent, stack_radius)
    placements = np.asarray(placements, float)
    if placements.shape != (n, n_obj, 3):
        raise ValueError(f"placements must be ({n}, {n_obj}, 3), got {placements.shape}")
    p_plain, p_mirr = placements[:n_plain], placements[n_plain:]
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
