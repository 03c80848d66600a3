"""grasp_choice.py's shortest path of states (turn, branch) over a window's samples, batched over episodes and
both half-turns of the gripper (screening_arm.py judges every candidate with it).

    c, b, cost = best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost)

The costs are grasp_choice._best_path's (a state not followed or a joint jumping: BAD; a missing margin up to
MARGIN_CAP; TURN_RATE_WEIGHT per rad of turn); a path costing less than BAD meets every rule at every sample.
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


def _flat_states(x: np.ndarray, ks: np.ndarray) -> np.ndarray:
    """(..., S, N) of (..., C, S, B): the states (_states) of the arm branches ks, per sample."""
    *lead, C, S, B = x.shape
    y = np.moveaxis(x.reshape(*lead, C, S, 2, 4)[..., ks], -3, -4)  # (..., S, C, 2, K)
    return y.reshape(*lead, S, -1)


def _max_abs_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """max over the last axis of |a - b| by element-wise maxima (a reduction over a short axis is slow)."""
    out = np.abs(a[..., 0] - b[..., 0])
    for j in range(1, a.shape[-1]):
        np.maximum(out, np.abs(a[..., j] - b[..., j]), out=out)
    return out


def best_paths(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost):
    """grasp_choice._best_path over a batch of episodes and both half-turns at once: q (E, C, S, B, 6) the joints,
    q5f (E, C, S, B) the last joint half-turned, good / margin (E, 2, C, S, B) per half-turn, start (E, 2, C, B)
    the first state's cost, valid (E, S) the samples that count (the others skipped), may_turn (E, S) where the
    turn may change (elsewhere a change costs BAD), jumps (E, S) how far a joint may move into each sample;
    moves between turns to the neighbours nb (C, m) only, and
    between branches only within an arm branch (the two wrist branches of each; an arm branch changes only
    through a singular configuration, which no followed path passes), each episode's arm branches never
    followed left out (the episodes grouped by those). Returns (c (E, 2, S), b (E, 2, S), cost (E, 2)); a
    cost under BAD: every sample followed, no joint jumping, the turn changing only where it may."""
    E, F, C, S, B = good.shape
    live = good.reshape(E, F, C, S, 2, 4).any(axis=(1, 2, 3, 4))  # (E, 4) arm branches followed somewhere
    live[~live.any(axis=1)] = True
    cs, bs, cost = np.zeros((E, F, S), int), np.zeros((E, F, S), int), np.zeros((E, F))
    keys, inverse = np.unique(live, axis=0, return_inverse=True)
    for k, key in enumerate(keys):
        r = np.flatnonzero(inverse.ravel() == k)
        cs[r], bs[r], cost[r] = _paths_of(q[r], q5f[r], good[r], margin[r], start[r], valid[r], may_turn[r],
                                          jumps[r], (nb, nb_mask, nb_cost), np.flatnonzero(key))
    return cs, bs, cost


def _paths_of(q, q5f, good, margin, start, valid, may_turn, jumps, moves, ks):
    """best_paths for episodes sharing the arm branches ks that are followed somewhere."""
    E, F, C, S, B = good.shape
    K = len(ks)
    Q04 = np.moveaxis(_flat_states(np.moveaxis(q[..., :5], -1, 0), ks), 0, -1).astype(np.float32)  # (E, S, N, 5)
    Q5 = np.stack([_flat_states(q[..., 5], ks), _flat_states(q5f, ks)], axis=1).astype(np.float32)  # (E, 2, S, N)
    # costs in float32 (7 digits of a path's few hundred at most: the BAD threshold and the margins' order keep)
    node = _flat_states(BAD * ~good + (MARGIN_CAP - np.minimum(margin, MARGIN_CAP)), ks).astype(np.float32)
    st = start.reshape(E, F, C, 2, 4)[..., ks].reshape(E, F, -1).astype(np.float32)
    pred, move, turning = _states(*moves, K)
    move = move.astype(np.float32)
    thresholds = jumps.astype(np.float32)
    N = pred.shape[0]
    cost = st + node[:, :, 0]
    back = np.zeros((E, F, S, N), np.int8)
    for s in range(1, S):
        jump = np.maximum(_max_abs_diff(Q04[:, s - 1][:, pred], Q04[:, s][:, :, None])[:, None],
                          np.abs(Q5[:, :, s - 1][:, :, pred] - Q5[:, :, s][..., None]))  # (E, 2, N, P)
        step = move + np.float32(BAD) * (turning & ~may_turn[:, s, None, None])  # (E, N, P)
        total = cost[:, :, pred] + step[:, None] + np.float32(BAD) * (jump >= thresholds[:, s, None, None, None])
        arg = np.argmin(total, axis=3)
        new = np.take_along_axis(total, arg[..., None], axis=3)[..., 0] + node[:, :, s]
        keep = ~valid[:, s, None, None]
        cost = np.where(keep, cost, new)
        back[:, :, s] = np.where(keep, 0, arg)
    n = cost.argmin(axis=2)  # (E, 2)
    best = np.take_along_axis(cost, n[..., None], axis=2)[..., 0]
    ns = np.empty((E, F, S), int)
    e, f = np.arange(E)[:, None], np.arange(F)[None]
    for s in range(S - 1, -1, -1):
        ns[:, :, s] = n
        if s:
            n = pred[n, back[e, f, s, n]]
    c, w, k = np.unravel_index(ns, (C, 2, K))
    return c, 4 * w + ks[k], best.astype(float)


__all__ = ["best_paths"]
