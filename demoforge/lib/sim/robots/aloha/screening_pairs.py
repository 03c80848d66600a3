"""The two arms' witnesses checked against each other (screening.py): grasp_choice._pair_ok on the pairs of
half-turns, the best scoring first, and where every pair clashes grasp_choice's second choice, each arm
searched again around the other (screening_arm.search_again).

    gap, apart, slot = forearms(ctx, arms, cands, traj)

Both arms' sample steps, the gap the arms keep at each (_needed_gap: the demonstrated hands' distance) and each
witness's points at the steps they share are taken once per group of episodes (Shared) and reused by every
pair checked, the second choice and the smallest gap reported.
"""

from __future__ import annotations

import numpy as np

from .grasp_choice import ARM_GAP
from .screening_arm import ArmScreen, ArmsContext, search_again
from .screening_points import Obstacle, hand_points, min_distance, norm3, radius, segments
from .screening_windows import rotations


def _needed_gap(ctx: ArmsContext, traj: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(n, M) the gap the arms keep at steps (n, M): ARM_GAP, or as far as the demonstrated hands' points were
    (grasp_choice._demonstrated_gap, of the smoothed poses traj (n, T, 2, 8)) less 1 cm."""
    e = np.arange(len(traj))[:, None]
    pose = traj[e, steps]  # (n, M, 2, 8)
    pts = hand_points(ctx, pose[..., :3], rotations(pose))  # (n, M, 2, 6, 3)
    return np.minimum(ARM_GAP, min_distance(pts[:, :, 0], pts[:, :, 1]) - 0.01)


def _track(res: ArmScreen, rows: np.ndarray, slot) -> dict:
    """An arm's witness (slot: int or (n,)) in episodes rows: its sample steps, which are its own, the joints
    and the hand's points along it."""
    k = np.broadcast_to(slot, rows.shape)
    return {"steps": res.steps[rows], "valid": res.valid[rows], "q": res.wit_q[rows, k],
            "hand": res.wit_hand[rows, k]}


def _points_at(ctx: ArmsContext, base, tr: dict, steps: np.ndarray) -> np.ndarray:
    """(n, M, 16, 3) grasp_choice._points_at: an arm's forearm segments (its witness's joints interpolated) and
    its hand's points (at the nearest sample) at steps (n, M); NaN outside its window's samples."""
    xp, valid, n = tr["steps"], tr["valid"], len(steps)
    count = valid.sum(axis=1)
    e = np.arange(n)[:, None]
    hi = np.minimum(((xp[:, None, :] <= steps[:, :, None]) & valid[:, None, :]).sum(axis=2), count[:, None] - 1)
    lo = np.maximum(np.where(xp[e, hi] > steps, hi - 1, hi), 0)
    x0, x1 = xp[e, lo], xp[e, hi]
    w = np.clip(np.where(x1 > x0, (steps - x0) / np.maximum(x1 - x0, 1), 0.0), 0.0, 1.0)[..., None]
    q = (1 - w) * tr["q"][e, lo] + w * tr["q"][e, hi]
    near = np.abs(np.where(valid[:, None, :], xp[:, None, :], 10 ** 9) - steps[:, :, None]).argmin(axis=2)
    out = segments(ctx, base, q, extra=6)
    out[..., 10:, :] = tr["hand"][e, near]
    out[(steps < xp[:, :1]) | (steps > xp[np.arange(n), count - 1][:, None])] = np.nan
    return out


def _pair_gap(p0: np.ndarray, p1: np.ndarray, use: np.ndarray, needed: np.ndarray, r0=None,
              r1=None) -> tuple[np.ndarray, np.ndarray]:
    """(smallest gap (n,) m, kept (n,)) of two arms' points (n, M, P, 3) at the shared steps use (n, M): kept where
    every gap is at least the needed one (n, M). The sets' bounding spheres first (closer_bound: about each
    set's first point, radii r0, r1 (n, M) if known): the points' distances only where those come within
    ARM_GAP."""
    r0, r1 = (radius(p) if r is None else r for p, r in ((p0, r0), (p1, r1)))
    with np.errstate(invalid="ignore"):
        close = use & ~(norm3(p0[..., 0, :] - p1[..., 0, :]) - r0 - r1 >= ARM_GAP)
    g = np.full(use.shape, np.inf)
    g[close] = min_distance(p0[close], p1[close])
    with np.errstate(invalid="ignore"):
        kept = ~(use & ~(g >= needed)).any(axis=1)
    return g.min(axis=1), kept


class Shared:
    """Both arms' witnesses in the episodes rows where both windows run: every sample step of either where
    both run (steps (n, M), use (n, M): grasp_choice._pair_ok's np.union1d within the overlap), the gap needed
    there and at each arm's own samples (the same function of the step), and each witness's points at the
    shared steps (taken once, on first use)."""

    def __init__(self, ctx: ArmsContext, traj: np.ndarray, arms: list, rows: np.ndarray):
        self.ctx, self.arms, self.rows = ctx, arms, rows
        n = len(rows)
        st = [r.steps[rows] for r in arms]
        va = [r.valid[rows] for r in arms]
        self.arm_needed = [_needed_gap(ctx, traj[rows], s) for s in st]
        lo = np.maximum(st[0][:, 0], st[1][:, 0])
        hi = np.minimum(*[s[np.arange(n), v.sum(axis=1) - 1] for s, v in zip(st, va)])
        every = np.concatenate([np.where(va[0], st[0], -1), np.where(va[1], st[1], -1)], axis=1)
        order = np.argsort(every, axis=1, kind="stable")
        both = np.take_along_axis(every, order, axis=1)
        need = np.take_along_axis(np.concatenate(self.arm_needed, axis=1), order, axis=1)
        self.use = (both >= lo[:, None]) & (both <= hi[:, None]) & np.concatenate(
            [np.ones((n, 1), bool), both[:, 1:] != both[:, :-1]], axis=1)
        self.steps = np.where(self.use, both, lo[:, None])
        self.needed = np.where(self.use, need, np.nan)  # (the steps not used count for nothing)
        self._points: dict = {}

    def points(self, a: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """((n, M, 16, 3), their first-point spheres' radii (n, M)) arm a's witness k (half-turn) at the shared
        steps."""
        if (a, k) not in self._points:
            pts = _points_at(self.ctx, self.ctx.bases[a], _track(self.arms[a], self.rows, k), self.steps)
            self._points[a, k] = pts, radius(pts)
        return self._points[a, k]

    def of_slots(self, a: int, slot: np.ndarray, sub: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arm a's points and radii at the shared steps of the rows sub (indices into rows) for their witnesses
        slot (len(sub),)."""
        p0, r0 = self.points(a, 0)
        pts, rad = np.empty((len(sub),) + p0.shape[1:]), np.empty((len(sub),) + r0.shape[1:])
        # each row copied once from its slot's points (a where() over both copies costs three times), the
        # half-turned witness's points made only if some row keeps it
        for k in (0, 1):
            at = np.flatnonzero(slot == k)
            if len(at):
                p, r = self.points(a, k)
                pts[at], rad[at] = p[sub[at]], r[sub[at]]
        return pts, rad


def forearms(ctx: ArmsContext, arms: list, cands: list, traj: np.ndarray) -> tuple[np.ndarray, ...]:
    """(gap (E,) m, apart (E,), slot (E, 2) each arm's witness kept): the pairs of witnesses (half-turns), the
    best scoring first, until one keeps the gap (a pair whose points are those of one already refused is
    refused with it); else, as grasp_choice, each arm chosen again around the other's best witness (_again).
    An arm alone: its best witness. gap: the smallest distance between the pair kept (or the best one)."""
    E = len(traj)
    gap, apart = np.full(E, np.inf), np.ones(E, bool)
    slot = np.stack([np.argmax(r.wit_score, axis=1) for r in arms], axis=1)
    r0, r1 = arms
    rows = np.flatnonzero(r0.active & r1.active & r0.feasible & r1.feasible)
    if not len(rows):
        return gap, apart, slot
    n, at = len(rows), np.arange(len(rows))
    score = np.stack([np.where(r0.wit_ok[rows, i] & r1.wit_ok[rows, j],
                               r0.wit_score[rows, i] + r1.wit_score[rows, j], -np.inf) for i in (0, 1) for j in (0, 1)],
                     axis=1)
    order = np.argsort(-score, axis=1, kind="stable")
    # the half-turn moves no point (the last joint's angle only): two witnesses on one path have the same points
    same = [np.isclose(r.wit_q[rows, 0, :, :5], r.wit_q[rows, 1, :, :5]).all(axis=(1, 2)) &
            np.isclose(r.wit_hand[rows, 0], r.wit_hand[rows, 1]).all(axis=(1, 2, 3)) for r in arms]
    sh = Shared(ctx, traj, arms, rows)
    refused, kept, last = np.zeros((n, 4), bool), np.zeros(n, bool), np.full(n, np.inf)
    for rank in range(4):
        pick = order[:, rank]
        i, j = np.divmod(pick, 2)
        twin = 2 * np.where(same[0], 1 - i, i) + np.where(same[1], 1 - j, j)  # a pair with the same points
        todo = np.flatnonzero(~kept & np.isfinite(score[at, pick]) & ~refused[at, twin])
        if not len(todo):
            continue
        (p0, r0), (p1, r1) = sh.of_slots(0, i[todo], todo), sh.of_slots(1, j[todo], todo)
        g, ok = _pair_gap(p0, p1, sh.use[todo], sh.needed[todo], r0, r1)
        refused[todo, pick[todo]] = ~ok
        slot[rows[todo[ok]]] = np.stack([i[todo[ok]], j[todo[ok]]], axis=1)
        kept[todo[ok]], last[todo[ok]] = True, g[ok]
    apart[rows] = kept
    done = kept.copy()
    if (~kept).any():
        found, g = _again(ctx, arms, cands, np.flatnonzero(~kept), traj, slot, sh)
        apart[rows[~kept]] = found
        done[np.flatnonzero(~kept)[found]], last[np.flatnonzero(~kept)[found]] = True, g[found]
    rest = np.flatnonzero(~done)  # neither kept nor found again: the best witnesses' gap
    if len(rest):
        (p0, r0), (p1, r1) = sh.of_slots(0, slot[rows[rest], 0], rest), sh.of_slots(1, slot[rows[rest], 1], rest)
        last[rest] = _pair_gap(p0, p1, sh.use[rest], sh.needed[rest], r0, r1)[0]
    gap[rows] = last
    return gap, apart, slot


def _again(ctx: ArmsContext, arms: list, cands: list, sub: np.ndarray, traj: np.ndarray, slot: np.ndarray,
           sh: Shared) -> tuple[np.ndarray, np.ndarray]:
    """(found (n,), the pair's smallest gap (n,)) grasp_choice's second choice for the rows sub (indices into
    sh.rows) whose witnesses clash: each arm in turn searched again with every state kept clear of the other's
    witness, the pair then checked. A pair found replaces the arm's witnesses (the first order that finds one:
    grasp_choice keeps the better scoring of the two)."""
    found, gap = np.zeros(len(sub), bool), np.full(len(sub), np.inf)
    for first in (0, 1):  # (the second order only where the first found nothing: one pair decides)
        part = sub[~found]
        if not len(part):
            break
        rows = sh.rows[part]
        second = 1 - first
        r1, r2 = arms[first], arms[second]
        avoid = Obstacle(_points_at(ctx, ctx.bases[first], _track(r1, rows, slot[rows, first]), r2.steps[rows]),
                         sh.arm_needed[second][part])
        for sel, c in cands[second]:
            inside = np.flatnonzero(np.isin(rows, sel))
            if c is None or not len(inside):
                continue
            again = search_again(ctx, c, r2, np.searchsorted(sel, rows[inside]), rows[inside],
                                 avoid.take(inside))
            k = np.argmax(again.wit_score, axis=1)
            here = _points_at(ctx, ctx.bases[second], _track(again, np.arange(len(inside)), k), sh.steps[part[inside]])
            there, r_there = sh.of_slots(first, slot[rows[inside], first], part[inside])
            r_here = radius(here)
            (p0, r0), (p1, r1) = ((there, r_there), (here, r_here)) if first == 0 else ((here, r_here), (there, r_there))
            g, ok = _pair_gap(p0, p1, sh.use[part[inside]], sh.needed[part[inside]], r0, r1)
            better = again.feasible & again.active & ok
            take = inside[better]
            for name in ("wit_ok", "wit_score", "wit_turn", "wit_margin", "wit_q", "wit_hand"):
                getattr(r2, name)[rows[take]] = getattr(again, name)[better]
            slot[rows[take], second] = k[better]
            at = np.searchsorted(sub, part[take])
            found[at], gap[at] = True, g[better]
    return found, gap


__all__ = ["Shared", "forearms"]
