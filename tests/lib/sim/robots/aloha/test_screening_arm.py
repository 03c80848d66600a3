"""One arm's screening (lib/sim/robots/aloha/screening_arm.py): its joints and margins are the closed form's, written
in place or into scratch memory alike."""

from __future__ import annotations

import numpy as np

from demoforge.lib.geometry import quat_to_matrix, random_quaternions
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.screening_arm import ArmsContext, _solve


def test_the_screenings_joints_and_margins_are_the_closed_forms():
    """screening_arm._solve (ViperXBatchIK.solve_into: numba kernels, margins per joint) against ViperXBatchIK.solve's
    angles and half - |q - mid| of them, the half-turned grasp's last joint included, bit for bit."""
    ctx = ArmsContext(get_robot("aloha", "2f140").retargeting("pouring"))
    sv, base = ctx.solver, ctx.bases[0]
    rng = np.random.default_rng(11)
    pos = np.array([base.x, base.y, base.z + 0.3]) + rng.uniform(-0.5, 0.5, (5000, 3))
    R = quat_to_matrix(random_quaternions(5000, rng))
    q, m, q5f, mf = _solve(ctx, base, pos, R)
    want = sv.solve(base, pos, R).q
    assert np.array_equal(q, want)
    margins = sv.half - np.abs(want - sv.mid)
    assert np.array_equal(m, margins.min(axis=-1))
    off = want[..., 5] + np.pi - sv.mid[5]
    off -= 2.0 * np.pi * np.rint(off / (2.0 * np.pi))
    assert np.array_equal(q5f, off + sv.mid[5])
    assert np.array_equal(mf, np.minimum(margins[..., :5].min(axis=-1), sv.half[5] - np.abs(off)))


def test_joints_written_in_place_and_scratch_memory_are_the_same_numbers():
    """_solve into the rows `at` of longer arrays (as _solve_cells scatters) gives its compact answer there, and
    ArmsContext.scratch hands out the same memory again, filled afresh and shaped as asked."""
    ctx = ArmsContext(get_robot("aloha", "2f140").retargeting("pouring"))
    base = ctx.bases[0]
    rng = np.random.default_rng(12)
    pos = np.array([base.x, base.y, base.z + 0.3]) + rng.uniform(-0.5, 0.5, (3000, 3))
    R = quat_to_matrix(random_quaternions(3000, rng))
    at = np.sort(rng.choice(9000, 3000, replace=False))
    out = (np.zeros((9000, 8, 6)), np.zeros((9000, 8)), np.zeros((9000, 8)), np.zeros((9000, 8)))
    _solve(ctx, base, pos, R, out=out, at=at)
    for got, want in zip(out, _solve(ctx, base, pos, R)):
        assert np.array_equal(got[at], want)
    a = ctx.scratch("x", (4, 5, 6), -np.inf)
    a[...] = 1.0
    b = ctx.scratch("x", (3, 5), 0.0)
    assert b.shape == (3, 5) and (b == 0.0).all() and np.shares_memory(a, b)


def test_the_turn_paths_reach_is_every_paths_by_enumeration():
    """_on_paths (the poses some path of turns through passing poses reaches end to end) and _reach (the first
    sample no such path is left at) against every path enumerated on small random instances: moves to a
    neighbour only into a sample where the turn may change."""
    from itertools import product

    from demoforge.lib.sim.robots.aloha.screening_arm import _neighbours, _on_paths, _reach

    rng = np.random.default_rng(11)
    turns = np.radians(90.0) * np.arange(4) - np.pi  # four turns, each a neighbour of two others
    nb, mask, _ = _neighbours(turns, np.radians(90.0))
    E, C, S = 60, 4, 5
    ok = rng.random((E, C, S)) < 0.7
    may_turn = rng.random((E, S)) < 0.5
    on, dead = _on_paths(ok, may_turn, nb, mask), _reach(ok, may_turn, nb, mask)
    for e in range(E):
        want, furthest = np.zeros((C, S), bool), 0
        for path in product(range(C), repeat=S):
            moves_ok = [path[s] == path[s - 1] or (may_turn[e, s] and path[s - 1] in nb[path[s]][mask[path[s]]])
                        for s in range(1, S)]
            good = [ok[e, path[0], 0]] + [ok[e, path[s], s] and moves_ok[s - 1] for s in range(1, S)]
            run = next((s for s in range(S) if not good[s]), S)
            furthest = max(furthest, run)
            if run == S:
                want[list(path), range(S)] = True
        assert (on[e] == want).all(), e
        assert dead[e] == (-1 if furthest == S else furthest), e
    assert 0 < on.any(axis=(1, 2)).sum() < E and (dead >= 0).any()

