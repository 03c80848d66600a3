"""Which grasp each ViperX uses in its window: among the grasps equivalent for the held object (its symmetry
turns, lib/sim/robots/retarget.py) and the gripper's half-turn, the one the arm follows over the whole
window with the largest joint margins, from a short transit off its ready pose, with the two forearms
apart.

    choice = choose_grasps(solver, bases, ready, speed, hand, objs, held, symmetries, windows)
    choice.hand        # (T, 2, 4, 4) the pinch poses the arms follow (each window's turn applied)
    choice.arms        # (GraspChoice, GraspChoice)

Every candidate is judged on up to `SAMPLES` steps of the window with the arm's closed-form IK
(closed_form.py, all branches at once): it starts on the branch nearest the ready pose at the window's
first step (as the IK does, ik.py `candidates`) and follows the nearest branch from sample to sample
(as the warm-started IK does). A candidate is feasible when every sample lies within reach and inside
the joints' ranges, the branch never jumps (a wrist roll through its range's end) and the wrist stays
above the table. Among the feasible ones the score prefers joint margins up to `MARGIN_CAP` rad (more
margin buys nothing), then a short transit and a small turn (the demonstration's own grasp first).
Then the best few of each arm are paired, and the best pair whose forearms stay `FOREARM_GAP` apart
wherever both windows run is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.sim.robots.retarget import grasp_turns, turn_grasp

from .closed_form import ViperXBatchIK
from .model import BasePose

SAMPLES = 32  # steps of a window the choice looks at
MARGIN_CAP = 0.35  # rad: joint margin beyond this does not make a grasp better
JUMP = 1.0  # rad: a joint moving this much between two samples means the branch ends (a roll through +-pi)
WRIST_ABOVE_TABLE = 0.02  # m
FOREARM_GAP = 0.10  # m between the two arms' forearm-wrist-hand segments (links about 4 cm in radius)
TURN_STEP_MAX_DEG = 30.0  # the most an axially symmetric object's grasp turns between two samples
TURN_RATE_WEIGHT = 0.05  # path cost per rad the grasp turns
BAD = 100.0  # path cost of a sample not followed (out of reach or range, a jump, fingers in the table)
TRANSIT_WEIGHT = 0.05  # score per second of the slowest joint's transit from the ready pose
TURN_WEIGHT = 0.02  # score per rad of turn away from the demonstrated grasp
LIFT_TOLERANCE = 0.003  # m a candidate's fingertips may dip below the clearance (retargeting raises them)


@dataclass(frozen=True)
class GraspChoice:
    """An arm's grasp for its window: the turn (rad) about the held object's axis (object -1: none held),
    the gripper's half-turn, the closed form's smallest joint margin over the window (rad), whether every
    sample was within reach and range, and how many candidates were weighed."""
    arm: int
    object: int
    turn: float
    flip: bool
    margin: float
    feasible: bool
    candidates: int
    turn_range: float = 0.0  # rad the turn changes over the window (an axially symmetric object's grasp may)


@dataclass
class Choice:
    """hand (T, 2, 4, 4) the poses the arms follow; arms: each arm's choice; tracks: per arm (sample steps (S,),
    the closed-form joints (S, 6) on the branch followed) or None outside any window."""
    hand: np.ndarray
    arms: tuple[GraspChoice, GraspChoice]
    tracks: tuple = (None, None)


@dataclass
class _Ranked:
    """One arm's candidates (one per gripper half-turn), best first: the turn at each sample (S,), flip, score,
    feasibility, the smallest joint margin, tracked joints (S, 6)."""
    turns: list
    flips: list
    score: np.ndarray
    feasible: np.ndarray
    margin: np.ndarray
    q: list
    steps: np.ndarray


def _best_path(q, good, margin, turns, transit0, max_turn_step):
    """The cheapest sequence of states (turn c, branch b) over the samples: a state costs its missing margin (up
    to MARGIN_CAP) and BAD if not followed there; a move costs TURN_RATE_WEIGHT per rad of turn and BAD when a
    joint would jump; the turn changes by at most max_turn_step between samples. q (C, S, B, 6), good / margin
    (C, S, B), transit0 (C, B) the start's cost. Returns (c (S,), b (S,), cost)."""
    C, S, B = good.shape
    node = BAD * ~good + (MARGIN_CAP - np.minimum(margin, MARGIN_CAP))  # (C, S, B)
    dturn = np.abs(np.angle(np.exp(1j * (turns[:, None] - turns[None, :]))))  # (C, C)
    K = int((dturn[0] <= max_turn_step + 1e-9).sum())  # the same for every turn: they lie evenly on the circle
    nbr = np.argsort(dturn, axis=1, kind="stable")[:, :K]  # (C, K) the turns a state can come from
    move = TURN_RATE_WEIGHT * np.take_along_axis(dturn, nbr, axis=1)[:, :, None, None]  # (C, K, 1, 1)
    cost = transit0 + node[:, 0]
    back = np.zeros((S, C, B), int)  # the predecessor (k * B + b) of each state
    for s in range(1, S):
        prev = q[nbr, s - 1]  # (C, K, B, 6)
        jump = np.abs(prev[:, :, :, None] - q[:, s][:, None, None]).max(axis=-1)  # (C, K, B, B')
        total = (cost[nbr][..., None] + move + BAD * (jump >= JUMP)).reshape(C, K * B, B)
        arg = np.argmin(total, axis=1)  # (C, B')
        cost = np.take_along_axis(total, arg[:, None], axis=1)[:, 0] + node[:, s]
        back[s] = arg
    c, b = np.unravel_index(int(np.argmin(cost)), cost.shape)
    best = float(cost[c, b])
    cs, bs = np.empty(S, int), np.empty(S, int)
    for s in range(S - 1, -1, -1):
        cs[s], bs[s] = c, b
        if s:
            k, b = divmod(int(back[s, c, b]), B)
            c = int(nbr[c, k])
    return cs, bs, best


def _rank(solver: ViperXBatchIK, base: BasePose, ready: np.ndarray, speed: np.ndarray, hand: np.ndarray,
          obj: np.ndarray | None, symmetry: int, steps: np.ndarray, lowest: Callable[[np.ndarray], np.ndarray]
          ) -> _Ranked:
    """One arm's candidates ranked (see the module docstring); lowest: (C, S, 4, 4) pinch poses -> (C, S) the
    fingertips' height above the table minus the clearance they must keep."""
    turns = grasp_turns(symmetry) if obj is not None else np.zeros(1)
    # any turn maps an axially symmetric object onto itself, so its grasp may turn along the window; an n-fold
    # one's only by whole steps, which it cannot make while held
    max_step = np.radians(TURN_STEP_MAX_DEG) if obj is not None and symmetry == 0 else 0.0
    out = {"turns": [], "flips": [], "score": [], "feasible": [], "margin": [], "q": []}
    for flip in (False, True):
        P = np.stack([turn_grasp(hand[steps], None if obj is None else obj[steps], t, flip) for t in turns])
        sol = solver.solve(base, P[..., :3, 3], P[..., :3, :3])
        q = sol.q  # (C, S, B, 6)
        good = sol.closes & sol.in_range
        good &= solver.points(base, q)["wrist"][..., 2] > WRIST_ABOVE_TABLE
        # a grasp whose fingers would have to be raised off the demonstrated pose is not the same grasp
        good &= (lowest(P) > -LIFT_TOLERANCE)[..., None]
        transit0 = (np.abs(q[:, 0] - ready) / speed).max(axis=-1)  # (C, B)
        start = TRANSIT_WEIGHT * transit0 + TURN_WEIGHT * np.abs(turns)[:, None]
        live = np.flatnonzero(good.any(axis=(0, 1)))  # branches followed somewhere (the others only cost BAD)
        live = live if len(live) else np.arange(good.shape[2])
        cs, bl, _ = _best_path(q[:, :, live], good[:, :, live], sol.margin[:, :, live], turns, start[:, live], max_step)
        bs = live[bl]
        idx = np.arange(len(steps))
        followed = good[cs, idx, bs]
        feasible = bool(followed.all())
        low = float(sol.margin[cs, idx, bs].min())
        turn = np.unwrap(turns[cs])
        score = (10.0 + min(low, MARGIN_CAP) - TRANSIT_WEIGHT * transit0[cs[0], bs[0]] if feasible
                 else float(np.argmin(followed)) / len(steps)) - TURN_WEIGHT * float(np.abs(turn).mean())
        for k, v in (("turns", turn), ("flips", flip), ("score", score), ("feasible", feasible), ("margin", low),
                     ("q", q[cs, idx, bs])):
            out[k].append(v)
    order = np.argsort(-np.array(out["score"]), kind="stable")
    pick = lambda k: [out[k][i] for i in order]  # noqa: E731
    return _Ranked(pick("turns"), pick("flips"), np.array(pick("score")), np.array(pick("feasible")),
                   np.array(pick("margin")), pick("q"), steps)


def _segment_points(solver: ViperXBatchIK, base: BasePose, q: np.ndarray, k: int = 5) -> np.ndarray:
    """(..., 2k, 3) points along the elbow -> wrist -> pinch segments of joints q (..., 6)."""
    p = solver.points(base, q)
    u = np.linspace(0.0, 1.0, k)[:, None]
    elbow, wrist, pinch = (p[n][..., None, :] for n in ("elbow", "wrist", "pinch"))
    return np.concatenate([elbow + u * (wrist - elbow), wrist + u * (pinch - wrist)], axis=-2)


def _forearm_gap(solver, bases, ranked: tuple[_Ranked, _Ranked], i: int, j: int, common: np.ndarray) -> float:
    """The smallest distance (m) between the two arms' forearm segments over the common samples."""
    if not len(common):
        return np.inf
    pts = []
    for a, r, c in ((0, ranked[0], i), (1, ranked[1], j)):
        at = np.searchsorted(r.steps, common)
        pts.append(_segment_points(solver, bases[a], r.q[c][np.minimum(at, len(r.steps) - 1)]))
    d = np.linalg.norm(pts[0][:, :, None] - pts[1][:, None, :], axis=-1)
    return float(d.min())


def choose_grasps(solver: ViperXBatchIK, bases: tuple[BasePose, BasePose], ready: np.ndarray, speed: np.ndarray,
                  hand: np.ndarray, objs: np.ndarray, held: np.ndarray, symmetries: np.ndarray,
                  windows: np.ndarray, lowest: Callable[[int, np.ndarray, np.ndarray], np.ndarray]) -> Choice:
    """Each arm's grasp (see the module docstring). hand (T, 2, 4, 4) demonstrated pinch poses; objs (T, n_obj,
    4, 4) the objects as demonstrated (retarget.object_trajectories); held (2,) the object each arm's window
    holds (-1 none); symmetries (n_obj,); windows (2, 2) [start, end); ready, speed (12,) both arms' joints;
    lowest(arm, steps, poses (C, S, 4, 4)) -> (C, S) the fingertips' height above the table less the clearance."""
    ranked: list[_Ranked | None] = [None, None]
    for a in range(2):
        w0, w1 = (int(v) for v in windows[a])
        if w1 <= w0:
            continue
        steps = np.unique(np.linspace(w0, w1 - 1, min(SAMPLES, w1 - w0)).round().astype(int))
        o = int(held[a])
        ranked[a] = _rank(solver, bases[a], ready[6 * a:6 * a + 6], speed[6 * a:6 * a + 6], hand[:, a],
                          objs[:, o] if o >= 0 else None, int(symmetries[o]) if o >= 0 else 1, steps,
                          lambda P, a=a, steps=steps: lowest(a, steps, P))
    pick = [0, 0]
    if ranked[0] is not None and ranked[1] is not None:
        common = np.intersect1d(np.arange(*windows[0]), np.arange(*windows[1]))
        common = common[np.unique(np.linspace(0, len(common) - 1, min(SAMPLES, len(common))).round().astype(int))] \
            if len(common) else common
        pairs = sorted(((i, j) for i in range(len(ranked[0].flips)) for j in range(len(ranked[1].flips))),
                       key=lambda ij: -(ranked[0].score[ij[0]] + ranked[1].score[ij[1]]))
        for i, j in pairs:
            if _forearm_gap(solver, bases, (ranked[0], ranked[1]), i, j, common) >= FOREARM_GAP:
                pick = [i, j]
                break
    out = np.array(hand, float)
    choices = []
    for a in range(2):
        r = ranked[a]
        o = int(held[a])
        if r is None:
            choices.append(GraspChoice(a, o, 0.0, False, np.nan, True, 0))
            continue
        i = pick[a]
        w0, w1 = (int(v) for v in windows[a])
        turn = np.interp(np.arange(w0, w1), r.steps, r.turns[i])  # the sampled turns, eased between samples
        out[w0:w1, a] = turn_grasp(hand[w0:w1, a], objs[w0:w1, o] if o >= 0 else None, turn, r.flips[i])
        choices.append(GraspChoice(a, o, float(turn[0]), bool(r.flips[i]), float(r.margin[i]), bool(r.feasible[i]),
                                   len(r.flips), float(np.ptp(turn))))
    tracks = tuple(None if r is None else (r.steps, r.q[pick[a]]) for a, r in enumerate(ranked))
    return Choice(out, (choices[0], choices[1]), tracks)


__all__ = ["Choice", "GraspChoice", "choose_grasps"]
