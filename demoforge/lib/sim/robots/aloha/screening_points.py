"""The point sets of grasp_choice.py's pair check, batched for the screening (screening.py, screening_arm.py):
an arm's forearm segments and hand points, the smallest distance between two sets, and the other arm as an
obstacle whose points are tested against many candidate sets at once.

    pts = hand_points(ctx, pos, R)              # (..., 6, 3) grasp_choice._hand_points
    d = min_distance(a, b)                      # grasp_choice._gap, in float32
    obstacle = Obstacle(points, gap)            # the other arm's points (n, S, 16, 3) and the gap (n, S)
    near = obstacle.near(a, e, s)               # point sets a (m, P, 3) at samples (e, s) closer than the gap

The obstacle's test is min_distance's, decided on a cheap bound first: the other arm's points form three
compact groups (its elbow -> wrist and wrist -> pinch points, its hand's), each held in a sphere; the points'
distances are taken only to the groups whose spheres come within the gap (a group left out is further than
the gap by more than any rounding, so the verdict is the full test's).
"""

from __future__ import annotations

import numba
import numpy as np

from .grasp_choice import HAND_SPREAD

# the other arm's points (screening._points_at): its elbow -> wrist and wrist -> pinch points, then its hand's
GROUPS = (slice(0, 5), slice(5, 10), slice(10, 16))
# m a sphere's test is looser than the exact one: far above the float32 distances' rounding (~1e-7 m)
SLACK = 1e-5
# point sets per pass of min_distance's kernel (its float32 planes stay in the first-level cache)
SETS = 64


def segments(ctx, base, q: np.ndarray, k: int = 5, extra: int = 0) -> np.ndarray:
    """(..., 2k + extra, 3) points along the elbow -> wrist -> pinch segments of joints q (..., 6)
    (grasp_choice._segment_points), then `extra` slots for the caller to fill."""
    return ctx.solver.segments(base, q, np.linspace(0.0, 1.0, k), extra)


def hand_points(ctx, pos: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(..., 6, 3) grasp_choice._hand_points of pinch poses (pos (..., 3), R (..., 3, 3)): the pinch point, the
    fingertips HAND_SPREAD to each side along the closing axis, the wrist centre behind along the approach
    axis and the palm's two sides half-way (a half-turn maps the set onto itself)."""
    x, z = R[..., :, 0], R[..., :, 2]
    palm = pos - 0.5 * ctx.w2p * z
    return np.stack([pos, pos + HAND_SPREAD * x, pos - HAND_SPREAD * x, pos - ctx.w2p * z,
                     palm + 0.5 * HAND_SPREAD * x, palm - 0.5 * HAND_SPREAD * x], axis=-2)


def min_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest distance between point sets a (..., P, 3) and b (..., Q, 3) (broadcast over ...; NaN where a
    point is NaN), in float32 (0.1 um at a metre: far below the centimetres the gaps are kept by): each pair's
    float32 squares summed x, y, z, the smallest taken, then its square root (_min_distance_kernel)."""
    lead = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    n = int(np.prod(lead))
    A, B = (np.ascontiguousarray(np.broadcast_to(x, lead + x.shape[-2:]).reshape(n, x.shape[-2], 3), float)
            for x in (a, b))
    return _min_distance_kernel(A, B).reshape(lead)


@numba.njit(cache=True)
def _min_distance_kernel(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(n,) min_distance of sets A (n, P, 3) and B (n, Q, 3) (float64, taken as float32), NaN where a pair's is.
    SETS at a time, copied into float32 planes coordinate, point, then set: the pairs' loop runs over the sets
    innermost, in SIMD lanes (five times the loop per set; numpy's planes of every pair cost a pass over
    memory per term)."""
    n, P, Q = A.shape[0], A.shape[1], B.shape[1]
    out = np.empty(n, np.float32)
    At, Bt = np.empty((3, P, SETS), np.float32), np.empty((3, Q, SETS), np.float32)
    best, nan = np.empty(SETS, np.float32), np.empty(SETS, np.bool_)
    for e0 in range(0, n, SETS):
        w = min(SETS, n - e0)
        for e in range(w):
            for c in range(3):
                for i in range(P):
                    At[c, i, e] = np.float32(A[e0 + e, i, c])
                for j in range(Q):
                    Bt[c, j, e] = np.float32(B[e0 + e, j, c])
        best[:] = np.float32(np.inf)
        nan[:] = False
        for i in range(P):
            for j in range(Q):
                for e in range(w):
                    dx, dy, dz = At[0, i, e] - Bt[0, j, e], At[1, i, e] - Bt[1, j, e], At[2, i, e] - Bt[2, j, e]
                    d = dx * dx
                    d += dy * dy
                    d += dz * dz
                    low = best[e]
                    best[e] = d if d < low else low
                    nan[e] |= d != d
        for e in range(w):
            out[e0 + e] = np.float32(np.nan) if nan[e] else np.sqrt(best[e])
    return out


def norm3(v: np.ndarray) -> np.ndarray:
    """|v| over the last axis (3), without a reduction over it."""
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def _sphere(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre (..., 3), radius (...)) of a sphere holding points a (..., P, 3): about the first point."""
    return a[..., 0, :], radius(a)


def radius(a: np.ndarray) -> np.ndarray:
    """(...) the radius of _sphere: the points' (..., P, 3) largest distance from the first (NaN where one is)."""
    flat = np.ascontiguousarray(a, float).reshape(-1, a.shape[-2], 3)
    return _radius_kernel(flat).reshape(a.shape[:-2])


@numba.njit(cache=True)
def _radius_kernel(a: np.ndarray) -> np.ndarray:
    """radius of sets a (n, P, 3): norm3's sum (x x + y y) + z z per point, the largest kept as np.maximum keeps
    it (NaN once one is NaN), in one loop per set (numpy's: a pass over memory per point and coordinate)."""
    n, P = a.shape[0], a.shape[1]
    out = np.empty(n)
    for e in range(n):
        r = 0.0
        for k in range(1, P):
            dx, dy, dz = a[e, k, 0] - a[e, 0, 0], a[e, k, 1] - a[e, 0, 1], a[e, k, 2] - a[e, 0, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if k == 1 or (r == r and (d > r or d != d)):
                r = d
        out[e] = r
    return out


def _centred_sphere(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre (..., 3), radius (...)) of a sphere holding points a (..., P, 3): about their mean (tighter than
    _sphere's for a segment's points; a bound only, so its rounding is covered by SLACK)."""
    c = a[..., 0, :].copy()
    for k in range(1, a.shape[-2]):
        c += a[..., k, :]
    c /= a.shape[-2]
    r = norm3(a[..., 0, :] - c)
    for k in range(1, a.shape[-2]):
        np.maximum(r, norm3(a[..., k, :] - c), out=r)
    return c, r


def closer_bound(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) a lower bound of the distance between point sets a (..., P, 3) and b (..., Q, 3): their spheres'."""
    (ca, ra), (cb, rb) = _sphere(a), _sphere(b)
    return norm3(ca - cb) - ra - rb


class Obstacle:
    """The other arm kept clear of: its points (n, S, 16, 3) at this arm's samples (NaN where it is not in its
    window: no constraint) and the gap (n, S) to keep from them, with its groups' spheres (GROUPS)."""

    def __init__(self, points: np.ndarray, gap: np.ndarray):
        self.points, self.gap = points, gap
        self.spheres = [_centred_sphere(points[..., g, :]) for g in GROUPS]
        self.finite = np.isfinite(points).all(axis=(-1, -2)) & np.isfinite(gap)

    def take(self, rows: np.ndarray) -> "Obstacle":
        """The same for the episodes `rows`."""
        out = Obstacle.__new__(Obstacle)
        out.points, out.gap, out.finite = self.points[rows], self.gap[rows], self.finite[rows]
        out.spheres = [(c[rows], r[rows]) for c, r in self.spheres]
        return out

    def near(self, a: np.ndarray, e: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(m,) bool: point sets a (m, P, 3) at the samples (e, s) (m,) come closer than the gap to the other
        arm's points: min_distance(a, points[e, s]) < gap[e, s] (False where a point or the gap is NaN)."""
        out = np.zeros(len(e), bool)
        live = np.flatnonzero(self.finite[e, s])
        if not len(live):
            return out
        a, e, s = a[live], e[live], s[live]
        gap = self.gap[e, s]
        ca, ra = _centred_sphere(a)
        with np.errstate(invalid="ignore"):
            for g, (cg, rg) in zip(GROUPS, self.spheres):
                maybe = np.flatnonzero((norm3(ca - cg[e, s]) - ra - rg[e, s] < gap + SLACK) & ~out[live])
                if len(maybe):
                    d = min_distance(a[maybe], self.points[e[maybe], s[maybe], g])
                    out[live[maybe]] = d < gap[maybe]
        return out

    def near_turned(self, points, e: np.ndarray, c: np.ndarray, s: np.ndarray, a0: np.ndarray, ctr: np.ndarray,
                    u: np.ndarray, turns: np.ndarray) -> np.ndarray:
        """near() for the point sets at the turns turns[c] (m,) of the sets a0 (n, S, P, 3) (turn turns[0]) about
        the axes u (n, S, 3) through ctr (n, S, 3) (a held object's); points(k) gives the sets (len(k), P, 3) of
        the cells k. A turn keeps each point's height along the axis and distance from it and adds to its angle
        about it, so two points come nearer than d where the cosine of their angle apart passes a bound, in
        closed form: a set is near where a pair passes it for gap - SLACK, clear where none passes it for
        gap + SLACK, and taken point by point (min_distance) in the rare band between."""
        out = np.zeros(len(e), bool)
        live = np.flatnonzero(self.finite[e, s])
        if not len(live):
            return out
        n, S = a0.shape[:2]
        es, inv = np.unique(e[live] * S + s[live], return_inverse=True)
        axis, centre = u.reshape(-1, 3)[es], ctr.reshape(-1, 3)[es]
        (ha, ra, xa, ya), (hb, rb, xb, yb) = (_cylindrical(x.reshape(n * S, -1, 3)[es], centre, axis)
                                              for x in (a0, self.points))
        gap = self.gap.reshape(-1)[es]
        t = turns - turns[0]
        near_at, band_at = _turned_bands(ha, ra, xa, ya, hb, rb, xb, yb, gap, np.cos(t), np.sin(t))
        cl = c[live]
        out[live] = near_at[inv, cl]
        band = live[band_at[inv, cl] & ~near_at[inv, cl]]
        if len(band):
            out[band] = min_distance(points(band), self.points[e[band], s[band]]) < self.gap[e[band], s[band]]
        return out


@numba.njit(cache=True, error_model="numpy")
def _turned_bands(ha, ra, xa, ya, hb, rb, xb, yb, gap, cos_t, sin_t):
    """(near (k, C), band (k, C)) of near_turned: per row k and turn, some pair of points (i of a's P, j of the
    other arm's Q, in cylindrical coordinates (k, P) and (k, Q) about the row's axis) comes nearer than
    gap - SLACK (near), or nearer than gap + SLACK (band). The pair's squared distance at a turn is base - twice
    cos(angle apart), so it passes a bound where that cosine exceeds (base - bound^2) / twice; a pair that
    never comes within gap + SLACK (the bound over 1) is skipped. One loop per row: numpy's (k, P, Q) planes and
    gathers of the passing pairs cost ten times this arithmetic."""
    k_n, P, Q, C = ha.shape[0], ha.shape[1], hb.shape[1], len(cos_t)
    near, band = np.zeros((k_n, C), np.bool_), np.zeros((k_n, C), np.bool_)
    for k in range(k_n):
        wide, tight = (gap[k] + SLACK) * (gap[k] + SLACK), (gap[k] - SLACK) * (gap[k] - SLACK)
        for i in range(P):
            for j in range(Q):
                dh = ha[k, i] - hb[k, j]
                base = dh * dh + ra[k, i] * ra[k, i] + rb[k, j] * rb[k, j]
                twice = 2.0 * ra[k, i] * rb[k, j]
                outer = (base - wide) / twice
                if not outer < 1.0:
                    continue
                inner = (base - tight) / twice
                ca = xa[k, i] * xb[k, j] + ya[k, i] * yb[k, j]
                sa = xa[k, i] * yb[k, j] - ya[k, i] * xb[k, j]
                for c in range(C):
                    cos = ca * cos_t[c] + sa * sin_t[c]
                    if cos > inner:
                        near[k, c] = True
                    if cos >= outer:
                        band[k, c] = True
    return near, band


def _cylindrical(x: np.ndarray, ctr: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """(height along the axis, distance from it, cosine and sine of the angle about it) (k, P) of points x
    (k, P, 3) about unit axes u (k, 3) through ctr (k, 3) (from a direction across the axis, the same for every
    point of a row; a point on the axis: angle 0)."""
    across = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    across /= norm3(across)[:, None]
    other = np.cross(u, across)
    v = x - ctr[:, None]
    h = np.einsum("kpi,ki->kp", v, u)
    px, py = np.einsum("kpi,ki->kp", v, across), np.einsum("kpi,ki->kp", v, other)
    r = np.hypot(px, py)
    safe = np.where(r > 0.0, r, 1.0)
    return h, r, np.where(r > 0.0, px / safe, 1.0), py / safe


__all__ = ["GROUPS", "Obstacle", "closer_bound", "hand_points", "min_distance", "norm3", "radius", "segments"]
