"""The screening's batched path search (lib/sim/robots/aloha/screening_paths.py) against a per-episode DP
written the way grasp_choice._best_path reads (arm branches left out, tie order, float32 sums included), on
random instances."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.sim.robots.aloha.grasp_choice import BAD, MARGIN_CAP
from demoforge.lib.sim.robots.aloha.screening_paths import best_paths

F32 = np.float32


def _plain_dp(q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost, e, f):
    """One episode's, one half-turn's cheapest path: states (turn c, wrist w, arm branch k) over the arm branches
    followed somewhere (all four if none), moves to a neighbour turn (j > 0 costs BAD where the turn may not
    change) and either wrist branch, BAD for a joint moving jumps[s] or more, a state's BAD when not followed
    plus its missing margin; float32 sums in that order, the first state and predecessor on ties."""
    C, S, B = good.shape[2:]
    live = [k for k in range(4) if good[e, :, :, :, [k, 4 + k]].any()] or list(range(4))
    states = [(c, w, k) for c in range(C) for w in range(2) for k in live]
    index = {st: n for n, st in enumerate(states)}
    j5 = q[e, ..., 5] if f == 0 else q5f[e]

    def node(s, c, w, k):
        b = 4 * w + k
        return F32(BAD * (not good[e, f, c, s, b]) + (MARGIN_CAP - min(margin[e, f, c, s, b], MARGIN_CAP)))

    def joints(c, s, b):
        return np.append(q[e, c, s, b, :5], j5[c, s, b]).astype(F32)

    cost = [F32(start[e, f, c, 4 * w + k]) + node(0, c, w, k) for c, w, k in states]
    back = np.zeros((S, len(states)), int)
    for s in range(1, S):
        if not valid[e, s]:
            continue
        new = []
        for n, (c, w, k) in enumerate(states):
            best, arg = None, 0
            for j in range(nb.shape[1]):
                for t in (0, 1):
                    cp, wp = nb[c, j], w ^ t
                    move = F32(nb_cost[c, j]) if nb_mask[c, j] else F32(np.inf)
                    step = move + F32(BAD) * F32(j > 0 and not may_turn[e, s])
                    jump = np.abs(joints(cp, s - 1, 4 * wp + k) - joints(c, s, 4 * w + k)).max()
                    total = (cost[index[cp, wp, k]] + step) + F32(BAD) * F32(jump >= F32(jumps[e, s]))
                    if best is None or total < best:
                        best, arg = total, 2 * j + t
            new.append(best + node(s, c, w, k))
            back[s, n] = arg
        cost = new
    n = last = int(np.argmin(cost))
    path = []
    for s in range(S - 1, -1, -1):
        c, w, k = states[n]
        path.append((c, 4 * w + k))
        if s:
            j, t = divmod(back[s, n], 2)
            n = index[nb[c, j], w ^ t, k]
    return path[::-1], float(cost[last])


def _instance(rng, E=6, C=5, S=7):
    """Random candidates: C turns on a circle (neighbours within one step), 8 branches (the wrist branches of an
    arm branch sharing its three joints, as the closed form's), followed states sparse enough that some arm
    branches are followed nowhere or lead nowhere, a window's last samples invalid."""
    nb = np.array([[c, (c - 1) % C, (c + 1) % C] for c in range(C)])
    nb_mask = np.ones_like(nb, bool)
    nb_cost = np.where(np.arange(3) == 0, 0.0, 0.013)[None].repeat(C, axis=0)
    q = rng.uniform(-np.pi, np.pi, (E, C, S, 8, 6)) * rng.uniform(0.0, 0.3, (E, 1, 1, 8, 1))
    q[..., 4:, :3] = q[..., :4, :3]  # the closed form's: the two wrist branches share the arm's three joints
    q5f = rng.uniform(-np.pi, np.pi, (E, C, S, 8))
    good = rng.random((E, 2, C, S, 8)) < rng.uniform(0.2, 0.9, (E, 1, 1, 1, 8))
    good[0, :, :, :, [1, 2, 3, 5, 6, 7]] = False  # one arm branch only
    good[1:3, :, :, :, [2, 3, 6, 7]] = False  # two arm branches followed somewhere ...
    good[1:3, 0, :, :, [0, 4]], good[1:3, 1, :, :, [0, 4]] = True, False  # ... the first by one half-turn only
    good[1:3, :, :, 3, [1, 5]] = False  # the second with a sample nowhere followed
    good[2, :, :, 2, [0, 4]] = False  # (and in the third episode neither has a path)
    margin = np.where(good, rng.uniform(0.05, 0.6, good.shape), rng.uniform(-0.3, 0.05, good.shape))
    margin[rng.random(good.shape) < 0.05] = -np.inf  # poses not solved
    start = rng.uniform(0.0, 0.2, (E, 2, C, 8))
    valid = np.ones((E, S), bool)
    valid[1, -2:] = False
    may_turn = rng.random((E, S)) < 0.6
    jumps = rng.choice([0.4, 0.6, 1.0], (E, S))
    return q, q5f, good | ~valid[:, None, None, :, None], margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost


def _assert_plain(args, seed):
    """best_paths' paths and costs are the plain DP's, and its witnesses (infeasible False) the same where feasible."""
    cs, bs, cost = best_paths(*args)
    witnesses = best_paths(*args, infeasible=False)
    E = len(cost)
    for e in range(E):
        for f in range(2):
            path, plain = _plain_dp(*args, e, f)
            assert [(int(c), int(b)) for c, b in zip(cs[e, f], bs[e, f])] == path, (seed, e, f)
            assert cost[e, f] == plain
            if plain < BAD:  # without the failed paths' details: the same witnesses
                assert witnesses[2][e, f] == plain and (witnesses[0][e, f] == cs[e, f]).all()
            else:
                assert not witnesses[2][e, f] < BAD


@pytest.mark.parametrize("seed", range(4))
def test_the_batched_path_search_is_the_plain_dp(seed):
    _assert_plain(_instance(np.random.default_rng(seed)), seed)


@pytest.mark.parametrize("seed", range(3))
def test_unsolved_joints_missing_neighbours_and_float32_margins(seed):
    """Joints not solved (NaN: a move from or to them never jumps, as numpy's maxima and >= have it), turns with
    fewer neighbours (nb_mask's padding: no move) and float32 margins (their cap subtracted in float32): still
    the plain DP's."""
    rng = np.random.default_rng(100 + seed)
    q, q5f, good, margin, start, valid, may_turn, jumps, nb, nb_mask, nb_cost = _instance(rng)
    arm = rng.random(q.shape[:3] + (4,)) < 0.1  # the arm's joints, shared by both wrist branches
    q[..., :3] = np.where(np.concatenate([arm, arm], axis=-1)[..., None], np.nan, q[..., :3])
    q[..., 3:][rng.random(q.shape[:4]) < 0.1] = np.nan
    q5f[rng.random(q5f.shape) < 0.1] = np.nan
    nb_mask[:, 1:] = rng.random((len(nb), 2)) < 0.6
    nb = np.where(nb_mask, nb, 0)
    args = q, q5f, good, margin.astype(np.float32), start, valid, may_turn, jumps, nb, nb_mask, nb_cost
    _assert_plain(args, seed)
