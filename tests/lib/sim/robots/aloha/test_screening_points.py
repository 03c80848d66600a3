"""The screening's point sets (lib/sim/robots/aloha/screening_points.py): the other arm's test against a held
object's turned hand, against the points' distances."""

from __future__ import annotations

import numpy as np

from demoforge.lib.sim.robots.aloha.screening_points import Obstacle, min_distance


def test_the_other_arm_near_a_turned_hand_is_the_point_test():
    """Obstacle.near_turned (pairs of points on arcs of turns about the held object's axis) against
    min_distance of the turned points, with gaps set near the sets' true distances."""
    rng = np.random.default_rng(7)
    n, S, P, Q, C = 5, 6, 9, 16, 24
    turns = np.radians(15.0) * np.arange(C)
    turns = np.where(turns > np.pi, turns - 2 * np.pi, turns)
    u = rng.normal(size=(n, S, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    ctr = rng.uniform(-0.2, 0.2, (n, S, 3))
    a0 = ctr[:, :, None] + rng.uniform(-0.25, 0.25, (n, S, P, 3))
    other = ctr[:, :, None] + rng.uniform(-0.3, 0.3, (n, S, Q, 3))

    def turned(x, th):  # Rodrigues about u through ctr
        v = x - ctr[:, :, None]
        par = u[:, :, None] * (v * u[:, :, None]).sum(-1, keepdims=True)
        return ctr[:, :, None] + par + np.cos(th) * (v - par) + np.sin(th) * np.cross(u[:, :, None], v)

    sets = np.stack([turned(a0, t) for t in turns], axis=2)  # (n, S, C, P, 3)
    exact = np.stack([min_distance(sets[:, :, c], other) for c in range(C)], axis=2)  # (n, S, C)
    gap = np.median(exact, axis=2) + rng.normal(0.0, 0.01, (n, S))
    gap[0, 0] = exact[0, 0, 3] + 2e-6  # within the band: decided point by point
    e, s, c = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(S), np.arange(C), indexing="ij"))
    want = min_distance(sets[e, s, c], other[e, s]) < gap[e, s]
    got = Obstacle(other, gap).near_turned(lambda k: sets[e[k], s[k], c[k]], e, c, s, a0, ctr, u, turns)
    assert (got == want).all() and 0 < want.sum() < len(want)
