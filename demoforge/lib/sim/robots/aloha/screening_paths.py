"""grasp_choice.py's shortest path of states (turn, branch) over a window's samples, batched over episodes and
both half-turns of the gripper (screening_arm.py judges every candidate with it).

    c, b, cost = best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost)

The costs are grasp_choice._best_path's (a state not followed or a joint jumping: BAD; a missing margin up to
MARGIN_CAP; TURN_RATE_WEIGHT per rad of turn); a path costing less than BAD meets every rule at every sample.
The sums are float32 in grasp_choice's order of additions, the ties broken as argmin's (the first state,
the first predecessor), so the paths are the plain per-episode DP's exactly.

The DP runs in numba kernels, one episode at a time over its own arm branches (no grouping, no copies): the
episode's joints (as float32) and state costs read once in the arrays' order, then per sample, state and
predecessor the largest joint move and the float32 sum, the cheapest kept with its back-pointer (selects, not
branches: which predecessor wins is unpredictable); then the backtrack. Numpy passes per sample over
(predecessor, state) planes of a few hundred elements spent ten times their arithmetic in call overhead.
No fastmath: the sums, NaN's propagation through the joints' maxima and the ties are numpy's exactly.
"""

from __future__ import annotations

import numba
import numpy as np

from .grasp_choice import BAD, MARGIN_CAP


def best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost, infeasible: bool = True):
    """grasp_choice._best_path over a batch of episodes and both half-turns at once: q (E, C, S, B, 6) the joints,
    q5f (E, C, S, B) the last joint half-turned, good / margin (E, 2, C, S, B) per half-turn, start (E, 2, C, B)
    the first state's cost, valid (E, S) the samples that count (the others skipped), may_turn (E, S) where the
    turn may change (elsewhere a change costs BAD), jumps (E, S) how far a joint may move into each sample;
    moves between turns to the neighbours nb (C, m) only, and
    between branches only within an arm branch (the two wrist branches of each; an arm branch changes only
    through a singular configuration, which no followed path passes), each episode's arm branches never
    followed left out. Returns (c (E, 2, S), b (E, 2, S), cost (E, 2)); a
    cost under BAD: every sample followed, no joint jumping, the turn changing only where it may.

    A path costing less than BAD keeps to one arm branch through followed states: the arm branches without
    such a path even when joints may jump (_reachable, on booleans) are left out first, which changes no
    such path nor its cost (the branches' states never meet). Where a half-turn has none, the paths are those
    of every branch followed somewhere, as grasp_choice's, or (infeasible False: the caller needs the paths
    that meet the rules only) left at cost inf."""
    E, F, C, S, B = good.shape
    live = _any_of_four(good.reshape(E, -1, 4))  # (E, 4) arm branches followed somewhere
    live[~live.any(axis=1)] = True
    reach = live.copy()
    multi = np.flatnonzero(live.sum(axis=1) > 1)  # (one branch: the paths are its own anyway)
    if len(multi):
        reach[multi] = _reachable(good, valid, may_turn, nb, nb_mask, multi)
    cs, bs, cost = np.zeros((E, F, S), int), np.zeros((E, F, S), int), np.full((E, F), np.inf)
    # the move costs as the DP adds them: float32, inf for no move
    move = np.where(nb_mask, nb_cost, np.inf).astype(np.float32)
    # MARGIN_CAP in the margins' type (numpy's np.minimum and subtraction keep a float32 margin float32)
    cap = margin.dtype.type(MARGIN_CAP)
    args = (q, q5f, good, margin, start, valid, may_turn, jumps.astype(np.float32), nb, move, BAD, cap)
    _paths(*args, reach, np.flatnonzero(reach.any(axis=1)), cs, bs, cost)
    if infeasible:  # (where no branch was left out, those are the paths already)
        again = ~(cost < BAD).all(axis=1) & (reach != live).any(axis=1)
        _paths(*args, live, np.flatnonzero(again), cs, bs, cost)
    return cs, bs, cost


def _any_of_four(x: np.ndarray) -> np.ndarray:
    """x.any(axis=1) of bools (E, M, 4), the four as one 32-bit word (an OR of words: a hundred times numpy's any
    over a middle axis)."""
    words = np.ascontiguousarray(x).view(np.uint32)[..., 0]  # (E, M)
    return np.bitwise_or.reduce(words, axis=1).view(np.uint8).reshape(len(x), 4).astype(bool)


@numba.njit(cache=True)
def _reachable(good, valid, may_turn, nb, nb_mask, rows):
    """(len(rows), 4) the arm branches of the episodes rows with a path of followed states over the samples in
    either half-turn (moves as best_paths', a joint free to jump). A state's eight branches are the bits of a
    byte (bit 4 w + k)."""
    E, F, C, S, B = good.shape
    out = np.zeros((len(rows), 4), np.bool_)
    r = np.zeros(C, np.int64)
    turn = np.zeros(C, np.int64)
    for i in range(len(rows)):
        e = rows[i]
        bits = 0
        for f in range(F):
            for c in range(C):
                r[c] = _byte(good, e, f, c, 0)
            for s in range(1, S):
                if not valid[e, s]:
                    continue
                for c in range(C):
                    turn[c] = (r[c] | (r[c] >> 4)) & 15  # the arm branches at each turn, either wrist branch
                for c in range(C):
                    came = turn[c]  # nb[:, 0] is the turn itself
                    if may_turn[e, s]:
                        for j in range(1, nb.shape[1]):
                            if nb_mask[c, j]:
                                came |= turn[nb[c, j]]
                    r[c] = _byte(good, e, f, c, s) & (came | (came << 4))
            for c in range(C):
                bits |= (r[c] | (r[c] >> 4)) & 15
        for k in range(4):
            out[i, k] = (bits >> k) & 1
    return out


@numba.njit(cache=True)
def _byte(good, e, f, c, s):
    """The branches followed in a state, bit b for branch b."""
    x = 0
    for b in range(good.shape[4]):
        if good[e, f, c, s, b]:
            x |= 1 << b
    return x


@numba.njit(cache=True)
def _max(a, b):
    """np.maximum's: NaN if either is."""
    return b if (b > a) | (b != b) else a


@numba.njit(cache=True)
def _node(good, margin, e, f, c, s, b, bad, cap):
    """A state's cost as numpy's float64 then rounded to float32: BAD if not followed, its missing margin (NaN
    kept as np.minimum keeps it)."""
    mg = margin[e, f, c, s, b]
    low = cap if mg >= cap else mg
    return np.float32((0.0 if good[e, f, c, s, b] else bad) + (cap - low))


@numba.njit(cache=True)
def _episode(q, q5f, good, margin, e, ks, K, bad64, cap, joints, node):
    """Episode e's states n = (2 c + w) K + k: joints (S, 7, N) their float32 joints (the arm's six, then the last
    half-turned), node (2, S, N) their costs. Read in the arrays' order (a state per sample, per turn, was ten
    times slower than the arithmetic: strided reads from memory)."""
    C, S = q.shape[1], q.shape[2]
    for c in range(C):
        for s in range(S):
            for w in range(2):
                for i in range(K):
                    n, b = (2 * c + w) * K + i, 4 * w + ks[i]
                    for j in range(6):
                        joints[s, j, n] = np.float32(q[e, c, s, b, j])
                    joints[s, 6, n] = np.float32(q5f[e, c, s, b])
    for f in range(2):
        for c in range(C):
            for s in range(S):
                for w in range(2):
                    for i in range(K):
                        n, b = (2 * c + w) * K + i, 4 * w + ks[i]
                        node[f, s, n] = _node(good, margin, e, f, c, s, b, bad64, cap)


@numba.njit(cache=True)
def _moves(nb, move, K, bad, pred, arm_pred, arm_at, step):
    """The moves into the states n = (2 c + w) K + k of K arm branches: pred (P, N) the predecessor 2 j + t (turn
    nb[c, j], the other wrist branch if t), arm_pred (m, N) / arm_at (N) the states whose arm joints count (wrist
    branch 0's: the two share them), step (2, P, N) the float32 move's cost, where the turn may change or not
    (BAD added to a turn's change)."""
    C, m = nb.shape
    zero = np.float32(0.0)
    for c in range(C):
        for w in range(2):
            for i in range(K):
                n = (2 * c + w) * K + i
                arm_at[n] = 2 * c * K + i
                for j in range(m):
                    arm_pred[j, n] = 2 * nb[c, j] * K + i
                    for t in range(2):
                        pred[2 * j + t, n] = (2 * nb[c, j] + (w ^ t)) * K + i
                        step[0, 2 * j + t, n] = move[c, j] + zero
                        step[1, 2 * j + t, n] = move[c, j] + (bad if j > 0 else zero)


@numba.njit(cache=True)
def _paths(q, q5f, good, margin, start, valid, may_turn, thr, nb, move, bad64, cap, branches, rows, cs, bs, out):
    """best_paths' DP for the episodes rows, each over its arm branches branches (E, 4), into cs, bs, out: thr
    (E, S) the jumps and move (C, m) the moves' costs in float32, bad64 / cap BAD and MARGIN_CAP (arguments: a
    cached kernel would not see them change)."""
    E, F, C, S, B = good.shape
    m, M = nb.shape[1], 8 * C
    bad = np.float32(bad64)
    joints, node = np.empty((S, 7, M), np.float32), np.empty((2, S, M), np.float32)
    cost, new, nan = np.empty((2, M), np.float32), np.empty((2, M), np.float32), np.empty((2, M), np.bool_)
    back = np.zeros((S, 2, M), np.int8)
    pred, arm_pred, arm_at = np.empty((2 * m, M), np.int64), np.empty((m, M), np.int64), np.empty(M, np.int64)
    step, arm = np.empty((2, 2 * m, M), np.float32), np.empty((m, M), np.float32)
    ks = np.empty(4, np.int64)
    for e in rows:
        K = 0
        for k in range(4):
            if branches[e, k]:
                ks[K] = k
                K += 1
        N = 2 * C * K
        _moves(nb, move, K, bad, pred, arm_pred, arm_at, step)
        _episode(q, q5f, good, margin, e, ks, K, bad64, cap, joints, node)
        for f in range(2):
            for c in range(C):
                for w in range(2):
                    for i in range(K):
                        n = (2 * c + w) * K + i
                        cost[f, n] = np.float32(start[e, f, c, 4 * w + ks[i]]) + node[f, 0, n]
        for s in range(1, S):
            if valid[e, s]:
                _step(joints[s - 1], joints[s], cost, new, nan, back[s], pred, arm_pred, arm_at,
                      step[0 if may_turn[e, s] else 1], thr[e, s], N, arm, bad)
                for f in range(2):
                    for n in range(N):
                        new[f, n] = (np.float32(np.nan) if nan[f, n] else new[f, n]) + node[f, s, n]
                cost, new = new, cost
        _backtrack(cost, back, valid, nb, e, ks, K, cs, bs, out)


@numba.njit(cache=True)
def _step(prev, cur, cost, new, nan, back, pred, arm_pred, arm_at, step, thr, N, arm, bad):
    """One sample's step: new (2, N) each state's cheapest total over its predecessors (the state's own cost not
    yet added), back (2, N) which (p of pred), in numpy's float32 order ((cost + step) + BAD if a joint moves thr
    or more), the first on ties; nan (2, N) where any total is NaN (back: P, past the last)."""
    P, zero = pred.shape[0], np.float32(0.0)
    for j in range(arm_pred.shape[0]):  # the arm's three joints (wrist branch 0's)
        for n in range(N):
            a, p = arm_at[n], arm_pred[j, n]
            d = _max(abs(prev[0, p] - cur[0, a]), abs(prev[1, p] - cur[1, a]))
            arm[j, n] = _max(d, abs(prev[2, p] - cur[2, a]))
    for n in range(N):
        best0, best1, arg0, arg1 = np.float32(np.inf), np.float32(np.inf), 0, 0
        nan0, nan1 = False, False
        for x in range(P):
            p = pred[x, n]
            jump = _max(_max(abs(prev[3, p] - cur[3, n]), abs(prev[4, p] - cur[4, n])), arm[x >> 1, n])
            tot0 = (cost[0, p] + step[x, n]) + (bad if _max(abs(prev[5, p] - cur[5, n]), jump) >= thr else zero)
            tot1 = (cost[1, p] + step[x, n]) + (bad if _max(abs(prev[6, p] - cur[6, n]), jump) >= thr else zero)
            nan0 |= tot0 != tot0
            nan1 |= tot1 != tot1
            less0, less1 = tot0 < best0, tot1 < best1
            best0, arg0 = (tot0 if less0 else best0), (x if less0 else arg0)
            best1, arg1 = (tot1 if less1 else best1), (x if less1 else arg1)
        new[0, n], back[0, n], nan[0, n] = best0, (P if nan0 else arg0), nan0
        new[1, n], back[1, n], nan[1, n] = best1, (P if nan1 else arg1), nan1


@numba.njit(cache=True)
def _backtrack(cost, back, valid, nb, e, ks, K, cs, bs, out):
    """Episode e's cheapest final state (argmin's: the first, or the first NaN) and its path back."""
    C, S = nb.shape[0], cs.shape[2]
    for f in range(2):
        n = 0
        for x in range(1, 2 * C * K):
            if cost[f, n] != cost[f, n]:
                break
            if cost[f, x] < cost[f, n] or cost[f, x] != cost[f, x]:
                n = x
        out[e, f] = cost[f, n]
        for s in range(S - 1, -1, -1):
            c, i = divmod(n, 2 * K)
            w, i = divmod(i, K)
            cs[e, f, s], bs[e, f, s] = c, 4 * w + ks[i]
            if s:
                p = back[s, f, n] if valid[e, s] else 0  # (numpy's 0 where skipped: the state itself)
                if p >= 2 * nb.shape[1]:
                    raise IndexError("a NaN cost on the path (numpy's back-pointer past the predecessors)")
                j, t = divmod(p, 2)
                n = (2 * nb[c, j] + (w ^ t)) * K + i


__all__ = ["best_paths"]
