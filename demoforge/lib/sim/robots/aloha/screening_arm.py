"""One arm's part of the screening (screening.py) over a batch of episodes: the candidate grasps of its window
(the held object's symmetric turns, the gripper's half-turn), their pose checks, and the search for a
*witness*, a candidate the arm follows over the window by grasp_choice.py's rules.

    cands, res = screen_arm(ctx, traj, held, obj0, windows[:, a], a, o)
    res.feasible        # (E,) some candidate is followed: the planner's own choice is then too
    res.wit_q           # (E, 2, SAMPLES, 6) the witness's joints per half-turn (slot 0 without, 1 with)
    res.reason          # (E,) for an arm that cannot: the first cause (an index into REASONS)
    again = search_again(ctx, cands, res, cand_rows, res_rows, avoid)   # the same, clear of the other arm

The batched pieces re-implement grasp_choice.py's private _best_path (screening_paths.py: over many
episodes and both half-turns at once), _segment_points, _hand_points and _gap (screening_points.py), and
retarget.py's turn_grasp and lowest_finger_z on the few numbers a check needs; the rules and their
constants are grasp_choice's, imported. The turned poses are made for every cell only for the pose checks;
the joints, the witnesses' hands and the other-arm tests take them cell by cell where wanted (_Poses).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from demoforge.lib.geometry import pose7_to_transform
from demoforge.lib.sim.robots.retarget import finger_half_width, grasp_turns

from .closed_form import SCREEN_CHUNK
from .grasp_choice import (BAD, GRIP_SETTLE_STEPS, HAND_SPREAD, JUMP, JUMP_PER_STEP, LIFT_TOLERANCE, MARGIN_CAP,
                           MIN_MARGIN, SAMPLES, TRANSIT_WEIGHT, TURN_RATE_WEIGHT, TURN_STEP_MAX_DEG, TURN_WEIGHT,
                           WRIST_ABOVE_TABLE)
from .screening_paths import best_paths
from .screening_points import Obstacle, hand_points
from .screening_windows import object_at_steps

REASONS = ("unreachable", "wrist_in_table", "fingers_in_table", "joint_limit", "branch_jump", "forearms_meet")
PASS = 64  # episodes per pass of the search over every turn at once (their joints: a few MB per episode)


class ArmsContext:
    """What every pass needs of the task's retargeting (retargeting.py ArmsRetargeting)."""

    def __init__(self, retarget):
        self.solver, self.bases, self.task, self.spec = retarget.solver, retarget.bases, retarget.task, retarget.spec
        self.ready, self.speed, self.clearance = retarget.ready, retarget.speed, retarget.clearance
        self.ko = np.asarray(self.task.keypoint_object, int)
        self.widths = np.append(self.task.grasp_widths, 0.0)  # index -1: nothing held
        self.symmetries = np.array([o.symmetry for o in self.task.objects], int)
        g = self.solver.g
        self.l1, self.l2, self.shoulder_z, self.w2p = g.l1, g.l2, g.shoulder_z, g.wrist_to_pinch
        self._scratch: dict = {}

    def scratch(self, name: str, shape: tuple, fill: float) -> np.ndarray:
        """An array of `shape` filled with `fill`, in memory kept for `name` from pass to pass: a pass's largest
        arrays (tens of MB) freshly allocated would have the kernel map and zero every page again (a fault per
        4 kB: about a tenth of the run). Valid until the next call with the same name."""
        size = int(np.prod(shape))
        if name not in self._scratch or len(self._scratch[name]) < size:
            self._scratch[name] = np.empty(size)
        out = self._scratch[name][:size].reshape(shape)
        out.fill(fill)
        return out


class ArmScreen:
    """One arm's screening of n episodes: its window's samples, whether some candidate is followed, the
    witnesses per half-turn (slot 0 without, 1 with), and for an arm that cannot follow its window the first
    cause (an index into REASONS) and the window step it shows at."""

    def __init__(self, n: int):
        self.active = np.zeros(n, bool)
        self.feasible = np.ones(n, bool)
        self.reason = np.full(n, -1)
        self.fail_step = np.full(n, np.iinfo(np.int64).max)
        self.steps = np.zeros((n, SAMPLES), int)
        self.valid = np.zeros((n, SAMPLES), bool)
        self.wit_ok = np.zeros((n, 2), bool)
        self.wit_score = np.full((n, 2), -np.inf)
        self.wit_turn = np.full((n, 2), np.nan)
        self.wit_margin = np.full((n, 2), np.nan)
        self.wit_q = np.zeros((n, 2, SAMPLES, 6))
        self.wit_hand = np.zeros((n, 2, SAMPLES, 6, 3))  # the hand's points (hand_points) along the witness
        self.best_margin = np.full(n, np.nan)  # an arm that cannot follow its window: along its best try

    def put(self, rows: np.ndarray, other: "ArmScreen") -> None:
        for k, v in vars(other).items():
            getattr(self, k)[rows] = v


def sample_steps(w0: np.ndarray, w1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(E, SAMPLES) the window steps grasp_choice looks at (np.linspace(w0, w1 - 1, min(SAMPLES, n)) rounded;
    a window of fewer steps takes each, its last repeated) and which of them are its own."""
    n = np.maximum(w1 - w0, 0)
    k = np.arange(SAMPLES)
    lin = np.round(np.linspace(w0, w1 - 1, SAMPLES, axis=1)).astype(int)
    few = w0[:, None] + np.minimum(k, np.maximum(n - 1, 0)[:, None])
    steps = np.where((n >= SAMPLES)[:, None], lin, few)
    return steps, k[None] < n[:, None]


class _Turner:
    """A hand's pinch poses P (E, S, 4, 4) turned about its held object's axis (objects' poses O (E, S, 4, 4),
    None: nothing held, only the turn 0): retarget.turn_grasp's O Rz(theta) O^-1 P by Rodrigues' formula on
    the position and the rotation's columns (each: its part along the axis, across it, and the axis x it)."""

    def __init__(self, P: np.ndarray, O: np.ndarray | None):
        self.P, self.O = P, O
        if O is None:
            return
        u, ctr = O[..., :3, 2], O[..., :3, 3]
        self.ctr = ctr
        vecs = np.stack([P[..., :3, 3] - ctr, P[..., :3, 0], P[..., :3, 1], P[..., :3, 2]], axis=-2)  # (E, S, 4, 3)
        self.par = u[..., None, :] * np.sum(u[..., None, :] * vecs, axis=-1, keepdims=True)
        self.perp = vecs - self.par
        self.cross = np.cross(u[..., None, :], vecs)

    def take(self, rows: np.ndarray) -> "_Turner":
        """The same for the episodes `rows`."""
        out = _Turner.__new__(_Turner)
        out.P, out.O = self.P[rows], None if self.O is None else self.O[rows]
        if self.O is not None:
            out.ctr, out.par, out.perp, out.cross = self.ctr[rows], self.par[rows], self.perp[rows], self.cross[rows]
        return out


class _Poses:
    """The pinch poses of the episodes rows (n,) of a _Turner turned by theta (n, C'), made cell by cell where
    wanted (turned_poses: the joints and the hand's points are wanted at some of the cells)."""

    def __init__(self, turner: _Turner, rows: np.ndarray, theta: np.ndarray):
        self.turner, self.rows, self.theta = turner, rows, theta

    def sub(self, k) -> "_Poses":
        return _Poses(self.turner, self.rows[k], self.theta[k])

    def at(self, e: np.ndarray, c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pos (k, 3), R (k, 3, 3)) of the cells: episode e (of rows), turn c (of theta's columns), sample s."""
        t = self.turner
        if t.O is None:
            P = np.take(t.P.reshape(-1, 4, 4), self.rows[e] * t.P.shape[1] + s, axis=0)
            return P[:, :3, 3].copy(), P[:, :3, :3].copy()
        return self.cells((e * self.theta.shape[1] + c) * t.P.shape[1] + s)

    def cells(self, cell: np.ndarray, out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """at() of the flat cells (k,) of (n, C', S) for a held object's turns (turned_poses), into out if given."""
        t = self.turner
        E, S = t.P.shape[:2]
        pos, R = (np.empty((len(cell), 3)), np.empty((len(cell), 3, 3))) if out is None else out
        theta = np.asarray(self.theta, float)  # (numpy's cos and sin on it)
        turned_poses(*(np.ascontiguousarray(x).reshape(E, S, 12) for x in (t.par, t.perp, t.cross)),
                     np.ascontiguousarray(t.ctr), np.asarray(self.rows, np.int64), np.cos(theta), np.sin(theta),
                     np.asarray(cell, np.int64), pos, R)
        return pos, R


@numba.njit(cache=True)
def turned_poses(par: np.ndarray, perp: np.ndarray, cross: np.ndarray, ctr: np.ndarray, rows: np.ndarray,
                 cos_t: np.ndarray, sin_t: np.ndarray, cells: np.ndarray, pos: np.ndarray, R: np.ndarray) -> None:
    """Pinch poses turned about a held object's axis (_Turner's parts, _Poses' cells) into pos
    (k, 3), R (k, 3, 3): the flat cells (k,) of (n, C, S) are episode rows[e], turn c (cos_t, sin_t (n, C)),
    sample s; par, perp, cross (E, S, 12) the parts of the pinch position - ctr (E, S, 3) and the rotation's
    columns along the axis, across it and the axis x it: v = par + cos perp + sin cross."""
    C, S = cos_t.shape[1], par.shape[1]
    for i in range(len(cells)):
        e, c, s = cells[i] // (C * S), cells[i] // S % C, cells[i] % S
        ep, ct, st = rows[e], cos_t[e, c], sin_t[e, c]
        for j in range(3):
            pos[i, j] = par[ep, s, j] + ct * perp[ep, s, j] + st * cross[ep, s, j] + ctr[ep, s, j]
            for col in range(3):
                x = 3 + 3 * col + j
                R[i, j, col] = par[ep, s, x] + ct * perp[ep, s, x] + st * cross[ep, s, x]


def _pose_checks(ctx: ArmsContext, base, turner: _Turner, turns: np.ndarray,
                 half: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(closes, wrist, fingers) (E, C, S) of the turner's pinch poses at every turn (C,) and sample: the wrist
    centre within the shoulder-elbow triangle's reach (closed_form.py: branch-independent), above
    WRIST_ABOVE_TABLE, and the fingertips' lowest point (retarget.lowest_finger_z: its minimum over the fingers'
    corners, taken term by term) at most LIFT_TOLERANCE below the clearance. half (E, S): each finger's
    distance from the pinch axis."""
    spec, l1, l2 = ctx.spec, ctx.l1, ctx.l2
    consts = np.array([ctx.w2p, base.x, base.y, base.z, ctx.shoulder_z, l1 ** 2, l2 ** 2, 2.0 * l1 * l2,
                       2.0 * spec.pad_half[0], spec.finger_thick, spec.pad_half[1], spec.tip_offset, ctx.clearance,
                       WRIST_ABOVE_TABLE, -LIFT_TOLERANCE], float)
    if turner.O is None:  # nothing held: the pose itself at every turn (the turn 0 only)
        E, S = half.shape
        par = np.empty((E, S, 4, 3))  # the position, then the x, y, z axes
        par[:, :, 0] = turner.P[..., :3, 3]
        par[:, :, 1:] = np.swapaxes(turner.P[..., :3, :3], -1, -2)
        zero, ctr = np.zeros_like(par), np.zeros((E, S, 3))
        return _pose_check_kernel(par, zero, zero, ctr, np.ones(len(turns)), np.zeros(len(turns)),
                                  np.asarray(half, float), consts)
    return _pose_check_kernel(turner.par, turner.perp, turner.cross, turner.ctr, np.cos(turns), np.sin(turns),
                              np.asarray(half, float), consts)


@numba.njit(cache=True)
def _pose_check_kernel(par, perp, cross, ctr, cos_t, sin_t, half, k):
    """_pose_checks' arithmetic per episode, turn and sample, in numpy's order of operations: the turned pose's
    numbers wanted (par + cos perp + sin cross of the position, approach and the x and y axes' heights; the
    vectors (E, S, 4, 3): position less ctr, then the x, y, z axes) and the three checks on them. k: the
    constants (see the caller). One loop: numpy's made eight (E, C, S) planes and a pass over memory each."""
    E, S, C = par.shape[0], par.shape[1], len(cos_t)
    closes = np.empty((E, C, S), np.bool_)
    wrist, fingers = np.empty_like(closes), np.empty_like(closes)
    w2p, bx, by, bz, sz, l1sq, l2sq, den, pad2, thick, pad1, tip, clear, above, low = (
        k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7], k[8], k[9], k[10], k[11], k[12], k[13], k[14])
    for e in range(E):
        for c in range(C):
            co, si = cos_t[c], sin_t[c]
            for s in range(S):
                p0 = par[e, s, 0, 0] + co * perp[e, s, 0, 0] + si * cross[e, s, 0, 0] + ctr[e, s, 0]
                p1 = par[e, s, 0, 1] + co * perp[e, s, 0, 1] + si * cross[e, s, 0, 1] + ctr[e, s, 1]
                p2 = par[e, s, 0, 2] + co * perp[e, s, 0, 2] + si * cross[e, s, 0, 2] + ctr[e, s, 2]
                a0 = par[e, s, 3, 0] + co * perp[e, s, 3, 0] + si * cross[e, s, 3, 0]
                a1 = par[e, s, 3, 1] + co * perp[e, s, 3, 1] + si * cross[e, s, 3, 1]
                a2 = par[e, s, 3, 2] + co * perp[e, s, 3, 2] + si * cross[e, s, 3, 2]
                xz = par[e, s, 1, 2] + co * perp[e, s, 1, 2] + si * cross[e, s, 1, 2]
                yz = par[e, s, 2, 2] + co * perp[e, s, 2, 2] + si * cross[e, s, 2, 2]
                w0, w1, w2 = p0 - w2p * a0, p1 - w2p * a1, p2 - w2p * a2
                dx, dy, h = w0 - bx, w1 - by, w2 - bz - sz
                reach = (dx * dx + dy * dy + h * h - l1sq - l2sq) / den
                closes[e, c, s] = abs(reach) <= 1.0
                wrist[e, c, s] = w2 > above
                xo = half[e, s] + pad2 + thick
                lowest = p2 - abs(xz) * xo - abs(yz) * pad1 + a2 * tip
                fingers[e, c, s] = lowest - clear > low
    return closes, wrist, fingers


def _solve(ctx: ArmsContext, base, pos: np.ndarray, R: np.ndarray, out: tuple | None = None,
           at: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """(q (n, 8, 6), margin (n, 8), the last joint of the half-turned grasp (n, 8), its margin) of pinch poses
    pos (n, 3), R (n, 3, 3), or written into the rows at (n,) of `out` (four arrays, those shapes but longer:
    no compact copy to scatter afterwards). The gripper's half-turn about its approach axis is the last joint's
    angle plus pi, nothing else (its range is a full turn: every other joint's margin stays). A joint's margin
    is half - |q - mid| of its range (ViperXBatchIK.solve_into: no (n, 8, 6) temporaries)."""
    n = len(pos)
    if out is None:
        out = np.empty((n, 8, 6)), np.empty((n, 8)), np.empty((n, 8)), np.empty((n, 8))
    at = np.arange(n) if at is None else np.asarray(at, np.int64)
    pos, R = np.ascontiguousarray(pos, float), np.ascontiguousarray(R, float)
    ctx.solver.solve_into(base, n, lambda i, j: (pos[i:j], R[i:j]), at, *out)
    return out


def _solve_cells(ctx: ArmsContext, base, poses: _Poses, cells: np.ndarray) -> tuple[np.ndarray, ...]:
    """_solve of the poses (n, C, S) where cells (n, C, S); elsewhere every branch out of range (margins -inf),
    its joints 0. (By flat indices, chunk by chunk straight into place; a held object's turns made by a kernel
    (turned_poses) chunk by chunk, not gathered from (k, 12) copies of the turner's parts first.)"""
    # (in ctx's scratch memory: every caller is done with a pass's joints before it solves the next)
    q = ctx.scratch("q", cells.shape + (8, 6), 0.0)
    m, q5f = ctx.scratch("m", cells.shape + (8,), -np.inf), ctx.scratch("q5f", cells.shape + (8,), 0.0)
    mf = ctx.scratch("mf", cells.shape + (8,), -np.inf)
    cell = np.flatnonzero(cells)
    if not len(cell):
        return q, m, q5f, mf
    flat = tuple(x.reshape((-1,) + x.shape[cells.ndim:]) for x in (q, m, q5f, mf))
    if poses.turner.O is None:
        _solve(ctx, base, *poses.at(*np.unravel_index(cell, cells.shape)), out=flat, at=cell)
        return q, m, q5f, mf
    buf = np.empty((min(len(cell), SCREEN_CHUNK), 3)), np.empty((min(len(cell), SCREEN_CHUNK), 3, 3))

    def turned(i, j):  # the poses of the cells i to j
        return poses.cells(cell[i:j], (buf[0][:j - i], buf[1][:j - i]))

    ctx.solver.solve_into(base, len(cell), turned, cell, *flat)
    return q, m, q5f, mf


def _neighbours(turns: np.ndarray, max_step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(nb (C, m) the turns a path may come from into each turn (itself first), their mask (C, m), and the
    cost of each move (C, m)): grasp_choice._best_path's moves without those costing BAD."""
    d = np.abs(np.angle(np.exp(1j * (turns[:, None] - turns[None, :]))))
    ok = d <= max_step + 1e-9
    m = int(ok.sum(axis=1).max())
    nb = np.zeros((len(turns), m), int)
    mask = np.zeros((len(turns), m), bool)
    for c in range(len(turns)):
        near = [c] + [j for j in np.flatnonzero(ok[c]) if j != c]
        nb[c, :len(near)], mask[c, :len(near)] = near, True
    return nb, mask, TURN_RATE_WEIGHT * np.take_along_axis(d, nb, axis=1)


def _transit(ctx: ArmsContext, a: int, q0: np.ndarray) -> np.ndarray:
    """(...) seconds of the slowest joint's move from the ready pose to joints q0 (..., 6)."""
    d = np.abs(q0 - ctx.ready[6 * a:6 * a + 6]) / ctx.speed[6 * a:6 * a + 6]
    out = d[..., 0]
    for j in range(1, 6):
        out = np.maximum(out, d[..., j])
    return out


@dataclass
class ArmCandidates:
    """One arm's candidates over a batch of episodes: the arm, its base, the turns and the moves between them
    (_neighbours), the max turn step, the poses (_Turner), which samples are the window's (E, S), the pose
    checks of every turn (E, C, S), where the turn may change (E, S), where the checks alone leave no path
    (E,: its sample, -1: none), and the other arm's segment points to keep clear of with the gap
    ((E, S, P, 3), (E, S)) or None."""
    a: int
    base: object
    turns: np.ndarray
    nb: tuple
    max_step: float
    turner: _Turner
    valid: np.ndarray
    ok: np.ndarray
    may_turn: np.ndarray
    dead: np.ndarray
    jumps: np.ndarray
    avoid: Obstacle | None = None

    def take(self, rows: np.ndarray, avoid: Obstacle | None = None) -> "ArmCandidates":
        """These episodes' candidates, kept clear of `avoid`."""
        return replace(self, turner=self.turner.take(rows), valid=self.valid[rows], ok=self.ok[rows],
                       may_turn=self.may_turn[rows], dead=self.dead[rows], jumps=self.jumps[rows], avoid=avoid)


def _judge(ctx: ArmsContext, arm: ArmCandidates, res: ArmScreen, rows: np.ndarray, cells, poses, sol,
           theta) -> np.ndarray:
    """Judge candidates of the episodes `rows`: poses (_Poses (n, C, S)) turned by theta
    (n, C) whose pose checks are cells (n, C, S) (C = 1: one fixed turn; else all turns, a turning path), and
    their joints sol (_solve: q (n, C, S, 8, 6) with margins m, the half-turned grasp's last joint q5f and
    margins mf (n, C, S, 8)). Stores the feasible ones as witnesses and, for the others, the furthest a path
    got. Returns which episodes got a witness."""
    q, m, q5f, mf = sol
    n, C, S = m.shape[:3]
    valid = arm.valid[rows]
    got = np.zeros(n, bool)
    at, idx, e = np.arange(n)[:, None], np.arange(S)[None], np.arange(n)
    clear = np.ones(m.shape, bool)
    if arm.avoid is not None:
        clear = _clear_of(ctx, arm, rows, cells, q, (m > MIN_MARGIN) | (mf > MIN_MARGIN))
    M = np.stack([m, mf], axis=1)  # (n, 2, C, S, B)
    good = ((M > MIN_MARGIN) & (cells[..., None] & clear)[:, None]) | ~valid[:, None, None, :, None]
    q0f = q[:, :, 0].copy()
    q0f[..., 5] = q5f[:, :, 0]
    transit = np.stack([_transit(ctx, arm.a, q[:, :, 0]), _transit(ctx, arm.a, q0f)], axis=1)  # (n, 2, C, B)
    start = TRANSIT_WEIGHT * transit + TURN_WEIGHT * np.abs(theta)[:, None, :, None]
    # the search around the other arm (arm.avoid) keeps the witnesses only: no infeasible path's details
    cs, bs, cost = best_paths(q, q5f, good, M, start, valid, arm.may_turn[rows], arm.jumps[rows], *arm.nb,
                              infeasible=arm.avoid is None)
    for slot in range(2):
        c, b = cs[:, slot], bs[:, slot]
        followed = good[at, slot, c, idx, b]
        feasible = cost[:, slot] < BAD
        marg = np.where(valid, M[at, slot, c, idx, b], np.inf).min(axis=1)
        turn = theta[at, c]  # (n, S) the turn along the path
        score = 10.0 + np.minimum(marg, MARGIN_CAP) - TRANSIT_WEIGHT * transit[e, slot, c[:, 0], b[:, 0]] \
            - TURN_WEIGHT * np.abs(turn).mean(axis=1)
        path = q[at, c, idx, b]  # (n, S, 6)
        if slot:
            path[..., 5] = q5f[at, c, idx, b]
        new = feasible & ~res.wit_ok[rows, slot]
        r = rows[new]
        res.wit_ok[r, slot], res.wit_score[r, slot] = True, score[new]
        res.wit_turn[r, slot], res.wit_margin[r, slot] = turn[new, 0], marg[new]
        res.wit_q[r, slot] = path[new]
        if len(r):
            pos, R = poses.at(np.repeat(np.flatnonzero(new), S), c[new].ravel(), np.tile(np.arange(S), len(r)))
            res.wit_hand[r, slot] = hand_points(ctx, pos, R).reshape(len(r), S, 6, 3)
        got |= feasible
        # the furthest an infeasible path got: its first sample not followed, and why
        first = np.argmin(followed | ~valid, axis=1)
        step = res.steps[rows, first]
        cf = c[e, first]
        some_branch = ((M[e, slot, cf, first] > MIN_MARGIN) & clear[e, cf, first]).any(axis=-1)
        later = ~feasible & (step > res.fail_step[rows])
        r = rows[later]
        res.reason[r] = np.where(some_branch[later], REASONS.index("branch_jump"),
                                 REASONS.index("joint_limit" if arm.avoid is None else "forearms_meet"))
        res.fail_step[r] = step[later]
        res.best_margin[r] = marg[later]
    return got


def _pose_points(ctx: ArmsContext, pos: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(..., 9, 3) the points of grasp_choice's pair check that the pinch pose alone places: the hand's
    (hand_points: the pinch point and the wrist centre among them) and the inner points of the wrist -> pinch
    segment (the wrist centre is the pose's, whatever the branch)."""
    wrist = pos - ctx.w2p * R[..., :, 2]
    u = np.linspace(0.0, 1.0, 5)[1:-1, None]
    return np.concatenate([hand_points(ctx, pos, R), wrist[..., None, :] + u * (pos - wrist)[..., None, :]], axis=-2)


def _clear_of(ctx: ArmsContext, arm: ArmCandidates, rows: np.ndarray, cells, q, in_range) -> np.ndarray:
    """(n, C, S, B) grasp_choice._paths' avoid: the states whose forearm segments and hand keep the gap from the
    other arm's points (arm.avoid; NaN where it is not in its window: no constraint), looked at only where the
    state could be followed otherwise (in range, the pose checks passed). The hand and the wrist -> pinch
    segment are the pose's (search_again checks them); the elbow -> wrist segment is the arm branch's (the two
    wrist branches share the elbow; the half-turn moves no point)."""
    n, C, S, B = in_range.shape
    live = cells[..., None] & arm.valid[rows][:, None, :, None] & (in_range[..., :4] | in_range[..., 4:])
    cell = np.flatnonzero(live & arm.avoid.finite[rows][:, None, :, None])
    e, c, s, k = np.unravel_index(cell, live.shape)
    joints = np.take(q.reshape(-1, 6), ((e * C + c) * S + s) * B + k, axis=0)  # wrist branch 0
    seg = ctx.solver.segments(arm.base, joints, np.linspace(0.0, 1.0, 5))[:, :5]  # (m, 5, 3) elbow -> wrist
    near = arm.avoid.near(seg, rows[e], s)
    clear = np.ones((n, C, S, 4), bool)
    clear[e[near], c[near], s[near], k[near]] = False
    return np.concatenate([clear, clear], axis=-1)


def screen_arm(ctx: ArmsContext, traj: np.ndarray, held: np.ndarray, obj0: np.ndarray, win: np.ndarray, a: int,
               o: int) -> tuple[ArmCandidates | None, ArmScreen]:
    """Arm a's window win (E, 2) in each episode of a group (smoothed poses traj (E, T, 2, 8), held (T, 2),
    the objects at the start obj0 (E, n_obj, 4, 4)), holding object o (-1: none): the pose checks of every
    turn and sample, then the search (search_arm). The candidates are None when no episode has the window."""
    E, T = traj.shape[:2]
    res = ArmScreen(E)
    res.active = win[:, 1] > win[:, 0]
    steps, res.valid = sample_steps(win[:, 0], np.maximum(win[:, 1], win[:, 0]))
    res.steps = steps = np.minimum(steps, T - 1)
    res.fail_step[:] = -1
    res.feasible[:] = ~res.active
    if not res.active.any():
        return None, res
    e = np.arange(E)[:, None]
    half = finger_half_width(traj[e, steps, a, 7], ctx.widths[held[steps, a]], ctx.spec.opening)
    turns, max_step, O = np.zeros(1), 0.0, None
    if o >= 0:
        sym = int(ctx.symmetries[o])
        turns, max_step = grasp_turns(sym), (np.radians(TURN_STEP_MAX_DEG) if sym == 0 else 0.0)
        O = object_at_steps(traj, held, obj0, o, steps)
    turner = _Turner(pose7_to_transform(traj[e, steps, a, :7]), O)
    closes, wrist, fingers = _pose_checks(ctx, ctx.bases[a], turner, turns, half)
    pad = ~res.valid[:, None, :]
    ok = (closes & wrist & fingers) | pad
    run = np.zeros(T, int)  # steps the hand has been closed for (grasp_choice: the turn changes once settled)
    closed = traj[0, :, a, 7] < 0.5
    for t in range(T):
        run[t] = run[t - 1] + 1 if closed[t] and t else int(closed[t])
    settled = run[steps] > GRIP_SETTLE_STEPS
    may_turn = np.concatenate([np.zeros((E, 1), bool), settled[:, 1:] & settled[:, :-1]], axis=1)
    nb = _neighbours(turns, max_step)
    # a joint may move JUMP between two samples, or JUMP_PER_STEP per demonstrated step between them if less
    jumps = np.minimum(JUMP, JUMP_PER_STEP * np.diff(steps, axis=1, prepend=steps[:, :1]))
    cands = ArmCandidates(a, ctx.bases[a], turns, nb, max_step, turner, res.valid, ok, may_turn,
                          _reach(ok, may_turn, *nb[:2]), jumps)
    search_arm(ctx, cands, res)
    code, at = _pose_reason(closes | pad, (closes & wrist) | pad, ok, cands.dead)
    out = res.active & ~res.feasible & (code >= 0)
    res.reason[out], res.fail_step[out] = code[out], steps[out, at[out]]
    return cands, res


def search_arm(ctx: ArmsContext, cands: ArmCandidates, res: ArmScreen) -> None:
    """Witnesses for the episodes of res that have none: the smallest turn whose poses pass the checks
    throughout first; for those it fails, every turn at once: fixed turns (_fixed_turns), or for an axially
    symmetric held object the turning paths (which the fixed turns are among)."""
    _fixed_turns(ctx, cands, res, first_only=True)
    if cands.max_step <= 0 or not cands.may_turn.any():
        _fixed_turns(ctx, cands, res, first_only=False)
        return
    rows = np.flatnonzero(res.active & ~res.feasible & (cands.dead < 0))
    for i in range(0, len(rows), PASS):
        part = rows[i:i + PASS]
        theta = np.broadcast_to(cands.turns, (len(part), len(cands.turns)))
        poses = _Poses(cands.turner, part, theta)
        # the joints only of the poses some path through poses that pass the checks reaches
        on = _on_paths(cands.ok[part], cands.may_turn[part], *cands.nb[:2]) & cands.valid[part][:, None, :]
        res.feasible[part] |= _judge(ctx, cands, res, part, cands.ok[part], poses,
                                     _solve_cells(ctx, cands.base, poses, on), theta)


def search_again(ctx: ArmsContext, cands: ArmCandidates, res: ArmScreen, cand_rows: np.ndarray, res_rows: np.ndarray,
                 avoid: Obstacle) -> ArmScreen:
    """The arm's search again over some episodes (cand_rows of cands, res_rows of res), every state kept clear
    of the other arm (avoid: its points at this arm's samples and the gap, screening_points.Obstacle):
    grasp_choice's second choice of an arm around the other."""
    again = ArmScreen(len(res_rows))
    again.active, again.steps, again.valid = res.active[res_rows], res.steps[res_rows], res.valid[res_rows]
    again.feasible[:], again.fail_step[:] = ~again.active, -1
    sub = cands.take(cand_rows, avoid)
    # the hand's and the wrist -> pinch segment's points depend on the pose only: a pose too near the other arm
    # fails with every branch (looked at where the pose passes the checks and the other arm is in its window)
    n, C, S = sub.ok.shape
    poses = _Poses(sub.turner, np.arange(n), np.broadcast_to(sub.turns, (n, C)))
    e, c, s = np.nonzero(sub.ok & sub.valid[:, None, :] & avoid.finite[:, None, :])

    def points(k):  # the cells' hand and wrist -> pinch points
        return _pose_points(ctx, *poses.at(e[k], c[k], s[k]))

    if sub.turner.O is None:
        near = avoid.near(points(np.arange(len(e))), e, s)
    else:  # the held object's turns: in closed form about its axis
        O = sub.turner.O
        first = poses.at(np.repeat(np.arange(n), S), np.zeros(n * S, int), np.tile(np.arange(S), n))
        near = avoid.near_turned(points, e, c, s, _pose_points(ctx, *first).reshape(n, S, -1, 3), O[..., :3, 3],
                                 O[..., :3, 2], sub.turns)
    sub.ok = sub.ok.copy()
    sub.ok[e[near], c[near], s[near]] = False
    sub.dead = _reach(sub.ok, sub.may_turn, *sub.nb[:2])
    search_arm(ctx, sub, again)
    return again


def _fixed_turns(ctx: ArmsContext, arm: ArmCandidates, res: ArmScreen, first_only: bool) -> None:
    """The turns whose poses pass the checks at every sample, each held fixed over the window: the smallest
    (the demonstration's grasp first) of each episode without a witness (first_only), or all of them at
    once (the path's cost picks among them, as grasp_choice's among its turns)."""
    viable = arm.ok.all(axis=2)
    rows = np.flatnonzero(res.active & ~res.feasible & viable.any(axis=1))
    if first_only:
        c = np.argmax(viable[rows], axis=1)
        theta = arm.turns[c][:, None]
        cells = arm.ok[rows, c][:, None]
    else:
        cols = np.flatnonzero(viable[rows].any(axis=0))  # the turns any of them may take
        rows, cols = (rows, cols) if len(cols) else (rows[:0], cols)
        theta = np.broadcast_to(arm.turns[cols], (len(rows), len(cols)))
        cells = arm.ok[rows][:, cols] & viable[rows][:, cols, None]  # a turn not viable fails at every sample
    poses = _Poses(arm.turner, rows, theta)
    for i in range(0, len(rows), PASS * 4):
        k = slice(i, i + PASS * 4)
        fixed = replace(arm, nb=(np.arange(theta.shape[1])[:, None], np.ones((theta.shape[1], 1), bool),
                                 np.zeros((theta.shape[1], 1))))
        on = cells[k] & arm.valid[rows[k]][:, None, :]
        got = _judge(ctx, fixed, res, rows[k], cells[k], poses.sub(k), _solve_cells(ctx, arm.base, poses.sub(k), on),
                     theta[k])
        res.feasible[rows[k][got]] = True


def _reach(ok: np.ndarray, may_turn: np.ndarray, nb: np.ndarray, nb_mask: np.ndarray) -> np.ndarray:
    """(E,) the first sample at which no path of turns (moving to neighbours where the turn may change)
    through poses that pass the checks ok (E, C, S) is left; -1: one runs through."""
    fwd = _sweep(np.ascontiguousarray(ok), np.ascontiguousarray(may_turn), nb, nb_mask, False)
    left = fwd.any(axis=1)  # (E, S)
    return np.where(left.all(axis=1), -1, np.argmin(left, axis=1))


def _on_paths(ok: np.ndarray, may_turn: np.ndarray, nb: np.ndarray, nb_mask: np.ndarray) -> np.ndarray:
    """(E, C, S) the poses (turn, sample) that some path of turns through poses that pass the checks ok (E, C, S)
    reaches from the first sample to the last (moving to neighbours where the turn may change)."""
    ok, may_turn = np.ascontiguousarray(ok), np.ascontiguousarray(may_turn)
    return _sweep(ok, may_turn, nb, nb_mask, False) & _sweep(ok, may_turn, nb, nb_mask, True)


@numba.njit(cache=True)
def _sweep(ok, may_turn, nb, nb_mask, backwards):
    """(E, C, S) the turns reached at each sample by paths through ok (E, C, S) from the first sample (or, backwards,
    from the last): a turn is reached where its pose passes and a turn reached at the sample before moves to it
    (itself, or a neighbour nb (C, m) where nb_mask and the turn may change into the later sample). One
    compiled loop per episode: numpy's took a pass per sample and neighbour slot."""
    E, C, S = ok.shape
    out = np.zeros((E, C, S), np.bool_)
    for e in range(E):
        s0 = S - 1 if backwards else 0
        for c in range(C):
            out[e, c, s0] = ok[e, c, s0]
        for i in range(1, S):
            s, prev = (S - 1 - i, S - i) if backwards else (i, i - 1)
            turn = may_turn[e, prev if backwards else s]  # the move between the two samples
            for c in range(C):
                if not ok[e, c, s]:
                    continue
                if not turn:
                    out[e, c, s] = out[e, c, prev]
                    continue
                for j in range(nb.shape[1]):
                    if nb_mask[c, j] and out[e, nb[c, j], prev]:
                        out[e, c, s] = True
                        break
    return out


def _pose_reason(closes: np.ndarray, wrist: np.ndarray, ok: np.ndarray, dead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(code (E,) into REASONS, -1 where the pose checks leave a path; sample (E,)): the first sample at
    which no turn is within reach (unreachable), none has its wrist above the table (wrist_in_table) or none
    its fingertips (fingers_in_table); where every sample has some turn but no path links them, the check
    most turns fail at the sample the last path ends."""
    E, C, S = ok.shape
    nones = [~np.any(x, axis=1) for x in (closes, wrist, ok)]  # (E, S) no turn passes the check
    firsts = np.stack([np.where(none.any(axis=1), np.argmax(none, axis=1), S) for none in nones], axis=1)
    code = np.argmin(firsts, axis=1)
    at = firsts[np.arange(E), code]
    stuck = (at >= S) & (dead >= 0)
    s = np.maximum(dead, 0)
    idx = np.arange(E)
    fails = np.stack([(~closes[idx, :, s]).sum(axis=1), (closes & ~wrist)[idx, :, s].sum(axis=1),
                      (wrist & ~ok)[idx, :, s].sum(axis=1)], axis=1)
    code = np.where(stuck, np.argmax(fails, axis=1), np.where(at < S, code, -1))
    return code, np.where(stuck, s, np.minimum(at, S - 1))


__all__ = ["ArmCandidates", "ArmScreen", "ArmsContext", "REASONS", "sample_steps", "screen_arm", "search_again",
           "search_arm"]
