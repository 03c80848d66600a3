"""grasp_choice.py's shortest path of states (turn, branch) over a window's samples, batched over episodes and
both half-turns of the gripper (screening_arm.py judges every candidate with it).

    c, b, cost = best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost)

The costs are grasp_choice._best_path's (a state not followed or a joint jumping: BAD; a missing margin up to
MARGIN_CAP; TURN_RATE_WEIGHT per rad of turn); a path costing less than BAD meets every rule at every sample.
The sums are float32 in grasp_choice's order of additions, the ties broken as argmin's (the first state,
the first predecessor), so the paths are the plain per-episode DP's exactly.
"""

from __future__ import annotations

import numpy as np

from .grasp_choice import BAD, MARGIN_CAP


def _states(nb: np.ndarray, nb_mask: np.ndarray, nb_cost: np.ndarray, K: int) -> tuple[np.ndarray, ...]:
    """The path's states (turn c, wrist branch w, arm branch k of K), n = (2 c + w) K + k, and where each can be
    reached from: (pred (N, P) the states, the state itself first; move (N, P) the cost of the move, inf for
    none; turning (N, P) the move changes the turn)."""
    C, m = nb.shape
    c, w, k = np.unravel_index(np.arange(C * 2 * K), (C, 2, K))
    j = np.repeat(np.arange(m), 2)  # neighbour slot, then the same wrist branch and the other
    ww = (w[:, None] + np.tile([0, 1], m)[None]) % 2
    pred = (2 * nb[c][:, j] + ww) * K + k[:, None]
    move = np.where(nb_mask[c][:, j], nb_cost[c][:, j], np.inf)
    return pred, move, np.broadcast_to(j > 0, pred.shape)


def best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost, infeasible: bool = True):
    """grasp_choice._best_path over a batch of episodes and both half-turns at once: q (E, C, S, B, 6) the joints,
    q5f (E, C, S, B) the last joint half-turned, good / margin (E, 2, C, S, B) per half-turn, start (E, 2, C, B)
    the first state's cost, valid (E, S) the samples that count (the others skipped), may_turn (E, S) where the
    turn may change (elsewhere a change costs BAD), jumps (E, S) how far a joint may move into each sample;
    moves between turns to the neighbours nb (C, m) only, and
    between branches only within an arm branch (the two wrist branches of each; an arm branch changes only
    through a singular configuration, which no followed path passes), each episode's arm branches never
    followed left out (the episodes grouped by those). Returns (c (E, 2, S), b (E, 2, S), cost (E, 2)); a
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
        reach[multi] = _reachable(good[multi], valid[multi], may_turn[multi], nb, nb_mask)
    cs, bs, cost = np.zeros((E, F, S), int), np.zeros((E, F, S), int), np.full((E, F), np.inf)
    _grouped(reach, reach.any(axis=1), (cs, bs, cost), q, q5f, good, margin, start, valid, may_turn, jumps,
             (nb, nb_mask, nb_cost))
    if infeasible:  # (where no branch was left out, those are the paths already)
        again = ~(cost < BAD).all(axis=1) & (reach != live).any(axis=1)
        _grouped(live, again, (cs, bs, cost), q, q5f, good, margin, start, valid, may_turn, jumps, (nb, nb_mask, nb_cost))
    return cs, bs, cost


def _grouped(branches, rows, out, q, q5f, good, margin, start, valid, may_turn, jumps, moves) -> None:
    """_paths_of for the episodes rows (E,) bool, grouped by their arm branches (E, 4) bool, into out."""
    sel = np.flatnonzero(rows)
    if not len(sel):
        return
    keys, inverse = np.unique(branches[sel], axis=0, return_inverse=True)
    for k, key in enumerate(keys):
        r = sel[inverse.ravel() == k]
        r = slice(None) if len(r) == len(rows) else r  # every episode: no copies
        res = _paths_of(q[r], q5f[r], good[r], margin[r], start[r], valid[r], may_turn[r], jumps[r], moves,
                        np.flatnonzero(key))
        for o, v in zip(out, res):
            o[r] = v


def _any_of_four(x: np.ndarray) -> np.ndarray:
    """x.any(axis=1) of bools (E, M, 4), the four as one 32-bit word (an OR of words: a hundred times numpy's any
    over a middle axis)."""
    words = np.ascontiguousarray(x).view(np.uint32)[..., 0]  # (E, M)
    return np.bitwise_or.reduce(words, axis=1).view(np.uint8).reshape(len(x), 4).astype(bool)


def _reachable(good, valid, may_turn, nb, nb_mask) -> np.ndarray:
    """(E, 4) the arm branches with a path of followed states over the samples in either half-turn (moves as
    best_paths', a joint free to jump). A state's eight branches are the bits of a byte (bit 4 w + k)."""
    E, F, C, S, B = good.shape
    g = np.packbits(good, axis=-1, bitorder="little")[..., 0]  # (E, F, C, S)
    r = g[:, :, :, 0]
    for s in range(1, S):
        turn = (r | (r >> 4)) & 15  # (E, F, C) the arm branches at each turn, either wrist branch
        moved = turn.copy()  # nb[:, 0] is the turn itself
        for j in range(1, nb.shape[1]):
            moved |= np.take(turn, nb[:, j], axis=2) * nb_mask[:, j].astype(np.uint8)
        came = np.where(may_turn[:, s, None, None], moved, turn)
        r = np.where(valid[:, s, None, None], g[:, :, :, s] & (came | (came << 4)), r)
    bits = np.bitwise_or.reduce(((r | (r >> 4)) & 15).reshape(E, -1), axis=1)
    return ((bits[:, None] >> np.arange(4)) & 1).astype(bool)


def _paths_of(q, q5f, good, margin, start, valid, may_turn, jumps, moves, ks):
    """best_paths for episodes sharing the arm branches ks that are followed somewhere. Laid out sample first and
    predecessor before state ((P, N) planes: numpy's reductions over a short last axis, and gathers with
    several index arrays, cost ten times the element-wise work), the costs in float32 (7 digits of a path's
    few hundred at most: the BAD threshold and the margins' order keep) added in grasp_choice's order."""
    E, F, C, S, B = good.shape
    K = len(ks)
    pred, move, turning = _states(*moves, K)
    N, P = pred.shape
    predT = pred.T.ravel()  # predecessor-major: (P, N) planes
    # the joints (S, 7, E, N): the arm's five, then the last per half-turn; per arm branch a float32 copy sample
    # first, then the joint axis moved in (two copies with short strides: a third faster than one long-strided)
    Q = np.empty((S, 7, E, C, 2, K), np.float32)
    q6, q5f6 = q.reshape(E, C, S, 2, 4, 6), q5f.reshape(E, C, S, 2, 4)
    for i, k in enumerate(ks):
        by_sample = np.ascontiguousarray(q6[..., k, :].transpose(2, 0, 1, 3, 4), np.float32)  # (S, E, C, 2, 6)
        Q[:, :6, ..., i] = by_sample.transpose(0, 4, 1, 2, 3)
        Q[:, 6, ..., i] = q5f6[..., k].transpose(2, 0, 1, 3)
    Q = Q.reshape(S, 7, E, N)
    g = good.reshape(E, F, C, S, 2, 4)[..., ks]
    mg = margin.reshape(E, F, C, S, 2, 4)[..., ks]
    node = np.ascontiguousarray((BAD * ~g + (MARGIN_CAP - np.minimum(mg, MARGIN_CAP))).transpose(3, 1, 0, 2, 4, 5),
                                dtype=np.float32).reshape(S, F, E, N)
    st = np.ascontiguousarray(start.reshape(E, F, C, 2, 4)[..., ks].transpose(1, 0, 2, 3, 4), dtype=np.float32)
    cost = st.reshape(F, E, N) + node[0]
    moveT = move.T.astype(np.float32)  # (P, N)
    turnT = turning.T
    thr = jumps.astype(np.float32)
    bad = np.float32(BAD)
    first_of = (P - np.arange(P)).astype(np.uint8)[:, None]  # P - p: the largest marks the first minimum (argmin's)
    back = np.zeros((S, F, E, N), np.int8)
    # the arm's three joints are the two wrist branches' own: their moves per (neighbour, turn, arm branch) only
    m = P // 2
    c_, k_ = np.divmod(np.arange(C * K), K)
    arm_from = ((2 * moves[0][c_] * K + k_[:, None]).T).ravel()  # (m, C K): the neighbour's wrist branch 0
    arm_to = 2 * c_ * K + k_
    for s in range(1, S):
        prev = np.take(Q[s - 1, :3], arm_from, axis=2).reshape(3, E, m, C * K)
        cur = np.take(Q[s, :3], arm_to, axis=2)[:, :, None]
        arm = np.abs(prev[0] - cur[0])
        for j in (1, 2):
            np.maximum(arm, np.abs(prev[j] - cur[j]), out=arm)
        prev = np.take(Q[s - 1, 3:5], predT, axis=2).reshape(2, E, P, N)
        cur = Q[s, 3:5, :, None]
        jump = np.maximum(np.abs(prev[0] - cur[0]), np.abs(prev[1] - cur[1]))
        # the arm's move into each state (both its wrist branches), broadcast over the predecessor's wrist branch
        # only (a long inner loop: broadcast over both, the innermost was K long)
        arm = np.repeat(arm.reshape(E, m, C, 1, K), 2, axis=3).reshape(E, m, 1, N)
        np.maximum(jump.reshape(E, m, 2, N), arm, out=jump.reshape(E, m, 2, N))
        j5 = np.abs(np.take(Q[s - 1, 5:], predT, axis=2).reshape(F, E, P, N) - Q[s, 5:, :, None])
        np.maximum(j5, jump, out=j5)
        step = moveT + bad * (turnT & ~may_turn[:, s, None, None])  # (E, P, N)
        total = np.take(cost, predT, axis=2).reshape(F, E, P, N) + step
        total += bad * (j5 >= thr[:, s, None, None])
        best = total.min(axis=2)
        arg = P - ((total == best[:, :, None]) * first_of).max(axis=2)
        keep = ~valid[:, s, None]
        cost = np.where(keep, cost, best + node[s])
        back[s] = np.where(keep, 0, arg)
    n = cost.argmin(axis=2)  # (F, E)
    best = np.take_along_axis(cost, n[..., None], axis=2)[..., 0]
    ns = np.empty((F, E, S), int)
    f, e = np.arange(F)[:, None], np.arange(E)[None]
    for s in range(S - 1, -1, -1):
        ns[:, :, s] = n
        if s:
            n = pred[n, back[s, f, e, n]]
    c, w, k = np.unravel_index(ns, (C, 2, K))
    return np.swapaxes(c, 0, 1), np.swapaxes(4 * w + ks[k], 0, 1), best.T.astype(float)


__all__ = ["best_paths"]
