"""The screening's point sets (lib/sim/robots/aloha/screening_points.py): the smallest distance between two sets
against the plain pairwise one, and the other arm's test against a held object's turned hand, against the
points' distances."""

from __future__ import annotations

import numpy as np

from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha.screening_arm import ArmsContext
from demoforge.lib.sim.robots.aloha.screening_points import Obstacle, min_distance, norm3, radius, segments


def test_the_smallest_distance_is_the_plain_pairwise_one():
    """min_distance (sets innermost) against every pair's float32 squares summed x, y, z and the minimum taken,
    bit for bit: NaN points, broadcast leading axes, sets of different sizes, no sets at all."""
    rng = np.random.default_rng(4)
    a, b = rng.normal(0.0, 0.3, (40, 7, 16, 3)), rng.normal(0.0, 0.3, (1, 7, 6, 3))
    a[3, 2, 5] = np.nan
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    d = (a32[..., :, None, 0] - b32[..., None, :, 0]) ** 2
    for k in (1, 2):
        d += (a32[..., :, None, k] - b32[..., None, :, k]) ** 2
    plain = np.sqrt(d.min(axis=(-1, -2)))
    got = min_distance(a, b)
    assert got.shape == (40, 7) and got.dtype == np.float32 and np.isnan(got[3, 2])
    assert np.array_equal(got, plain, equal_nan=True)
    assert min_distance(a[:0, 0], b[0, :0]).shape == (0,)


def test_the_segment_points_are_the_plain_interpolation():
    """segments (point by point, room left for the hand) against grasp_choice's elbow + u (wrist - elbow) and
    wrist + u (pinch - wrist) broadcast over u, bit for bit."""
    ctx = ArmsContext(get_robot("aloha", "2f140").retargeting("pouring"))
    q = np.random.default_rng(6).uniform(-1.5, 1.5, (30, 4, 6))
    p = ctx.solver.points(ctx.bases[1], q)
    u = np.linspace(0.0, 1.0, 5)[:, None]
    e, w, t = (p[k][..., None, :] for k in ("elbow", "wrist", "pinch"))
    got = segments(ctx, ctx.bases[1], q, extra=6)
    assert got.shape == (30, 4, 16, 3)
    assert np.array_equal(got[..., :10, :], np.concatenate([e + u * (w - e), w + u * (t - w)], axis=-2))


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


def test_the_sphere_radius_is_the_largest_distance_from_the_first_point():
    """screening_points.radius against norm3's largest distance from each set's first point, NaN where a point is."""
    a = np.random.default_rng(12).normal(size=(50, 7, 16, 3))
    a[3, 2, 5], a[4, 1, 0], a[5, 5, 1] = np.nan, np.nan, np.nan
    want = norm3(a[..., 1, :] - a[..., 0, :])
    for k in range(2, 16):
        np.maximum(want, norm3(a[..., k, :] - a[..., 0, :]), out=want)
    got = radius(a)
    assert got.shape == (50, 7) and np.isnan(got).sum() == 3
    assert np.array_equal(got, want, equal_nan=True)
