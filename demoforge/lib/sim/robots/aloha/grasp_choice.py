"""Which grasp each ViperX uses in its window: among the grasps equivalent for the held object (its symmetry
turns, lib/sim/robots/retarget.py) and the gripper's half-turn, the one the arm follows over the whole
window with the largest joint margins, from a short transit off its ready pose, clear of the other arm.

    choice = choose_grasps(solver, bases, ready, speed, hand, closed, objs, held, symmetries, windows, lowest)
    choice.hand        # (T, 2, 4, 4) the pinch poses the arms follow (each window's turns applied)
    choice.arms        # (GraspChoice, GraspChoice)

Every candidate is judged on up to `SAMPLES` steps of the window with the arm's closed-form IK
(closed_form.py, all branches at once). A state (turn, branch) at a sample is followed when the pose is
within reach, every joint `MIN_MARGIN` inside its range, the wrist and the fingertips above the table.
The choice is the cheapest path of states over the samples (`_best_path`): it starts near the ready pose
(as the IK does, ik.py `candidates`), no joint jumps between samples (a wrist roll through its range's
end), it prefers margins up to `MARGIN_CAP`, and the turn stays what it was at the grasp except while
the hand holds an axially symmetric object (any turn about its axis maps it onto itself, so the held object
still moves as demonstrated; not a thin one in a hand whose pads let it roll: aloha/retargeting.py), from `GRIP_SETTLE_STEPS` after the close on, and then changes by at
most `TURN_STEP_MAX_DEG` between samples.
The half-turn of the gripper holds for the whole window.

The two arms are chosen apart, then checked against each other where both windows run: their forearm,
wrist and hand segments and their hands' fingertips and palms must stay `ARM_GAP` apart, or as far as the
demonstrated hands were if they came closer. If not, each arm in turn is chosen again with the other's segments as obstacles, and the better
pair is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.sim.robots.retarget import grasp_turns, turn_grasp

from .closed_form import ViperXBatchIK
from .model import BasePose

SAMPLES = 32  # steps of a window the choice looks at
MIN_MARGIN = 0.05  # rad every joint keeps from its range's ends (the IK and the samples between steps move a little)
MARGIN_CAP = 0.35  # rad: joint margin beyond this does not make a grasp better
JUMP = 1.0  # rad: a joint moving this much between two samples means the branch ends (a roll through +-pi) ...
JUMP_PER_STEP = 0.2  # ... or this much per demonstrated step between them (6 rad/s at 30 fps: twice a servo's speed)
WRIST_ABOVE_TABLE = 0.02  # m
ARM_GAP = 0.12  # m between the two arms' forearm-wrist-hand segments and hands (links about 4 cm in radius)
HAND_SPREAD = 0.07  # m from the pinch axis to an open 2F-140's finger (half its 110 mm opening and the finger)
TURN_STEP_MAX_DEG = 30.0  # the most an axially symmetric held object's grasp turns between two samples
TURN_RATE_WEIGHT = 0.05  # path cost per rad the grasp turns
GRIP_SETTLE_STEPS = 15  # steps after a close before the grasp may turn (the fingers take about 0.45 s to close)
STRAIGHT_WRIST = 0.5  # sin(wrist angle) below which the wrist counts as near its singularity
SINGULAR_WEIGHT = 20.0  # path cost of a sample with the wrist straight (MARGIN_CAP: of one at a joint's range end)
BAD = 100.0  # path cost of a state not followed (out of reach or range, a jump, fingers in the table, the other arm)
TRANSIT_WEIGHT = 0.05  # score per second of the slowest joint's transit from the ready pose
TURN_WEIGHT = 0.02  # score per rad of turn away from the demonstrated grasp
LIFT_TOLERANCE = 0.003  # m a candidate's fingertips may dip below the clearance (retargeting raises them)


@dataclass(frozen=True)
class GraspChoice:
    """An arm's grasp for its window: the turn (rad) about the held object's axis at the window's start (object
    -1: none held) and how much it changes over the window, the gripper's half-turn, the closed form's
    smallest joint margin over the window (rad), whether every sample is followed, how many candidates
    (turn x half-turn) were weighed."""
    arm: int
    object: int
    turn: float
    flip: bool
    margin: float
    feasible: bool
    candidates: int
    turn_range: float = 0.0


@dataclass
class Choice:
    """hand (T, 2, 4, 4) the poses the arms follow; arms: each arm's choice; tracks: per arm (sample steps (S,),
    the closed-form joints (S, 6) on the branch followed) or None outside any window."""
    hand: np.ndarray
    arms: tuple[GraspChoice, GraspChoice]
    tracks: tuple = (None, None)


@dataclass
class _Window:
    """One arm's window as the choice sees it: its samples, poses, held object and its symmetry."""
    arm: int
    steps: np.ndarray
    hand: np.ndarray  # (S, 4, 4) demonstrated pinch poses at the samples
    obj: np.ndarray | None  # (S, 4, 4) the held object's poses at the samples
    symmetry: int
    may_turn: np.ndarray  # (S,) the turn may change from the previous sample (the object held at both)
    lowest: Callable[[np.ndarray], np.ndarray]
    # per half-turn (flip, poses (C, S, 4, 4), closed form, followed (C, S, B) before the other arm is weighed):
    # _states' answer, kept for the window's second choice around the other arm
    states: list | None = None


@dataclass
class _Path:
    """One arm's best path for one half-turn: turn (S,), joints (S, 6), score, feasible, smallest margin."""
    flip: bool
    turn: np.ndarray
    q: np.ndarray
    poses: np.ndarray  # (S, 4, 4) the pinch poses it follows at the samples
    score: float
    feasible: bool
    margin: float
    candidates: int


def _best_path(q, good, margin, turns, transit0, max_turn_step, may_turn, jumps):
    """The cheapest sequence of states (turn c, branch b) over the samples: a state costs its missing margin (up
    to MARGIN_CAP) and BAD if not followed there; a move costs TURN_RATE_WEIGHT per rad of turn and BAD when a
    joint would jump (more than jumps (S,) rad since the sample before) or the turn changes where it may not
    (may_turn (S,)). q (C, S, B, 6), good / margin (C, S, B), transit0 (C, B) the start's cost. Returns (c (S,),
    b (S,))."""
    C, S, B = good.shape
    # a wrist close to straight (wrist angle near 0) is the wrist's singularity: its two rolls then spin fast
    # for a small turn of the hand, so the path keeps away from it like from a joint's range end
    straight = np.abs(np.sin(q[..., 4]))
    node = (BAD * ~good + (MARGIN_CAP - np.minimum(margin, MARGIN_CAP))
            + SINGULAR_WEIGHT * np.maximum(STRAIGHT_WRIST - straight, 0.0) / STRAIGHT_WRIST)  # (C, S, B)
    dturn = np.abs(np.angle(np.exp(1j * (turns[:, None] - turns[None, :]))))  # (C, C)
    K = int((dturn[0] <= max_turn_step + 1e-9).sum())  # the same for every turn: they lie evenly on the circle
    nbr = np.argsort(dturn, axis=1, kind="stable")[:, :K]  # (C, K) the turns a state can come from (itself first)
    move = TURN_RATE_WEIGHT * np.take_along_axis(dturn, nbr, axis=1)[:, :, None, None]  # (C, K, 1, 1)
    held_still = move.copy()
    held_still[:, 1:] += BAD
    cost = transit0 + node[:, 0]
    back = np.zeros((S, C, B), int)  # the predecessor (k * B + b) of each state
    turn_rows, branch_cols = np.arange(C)[:, None], np.arange(B)[None, :]
    # every sample's jumps at once (S - 1, C, K, B, B'): from each state at the sample before to each state, the
    # joints' largest move taken joint by joint (numpy's reduction over a short last axis costs ten times more)
    jump = None
    for j in range(q.shape[-1]):
        qj = q[..., j].transpose(1, 0, 2)  # (S, C, B)
        d = np.abs(qj[:-1, nbr][..., None] - qj[1:, :, None, None])
        jump = d if jump is None else np.maximum(jump, d, out=jump)
    jumped = BAD * (jump >= jumps[1:, None, None, None, None])
    for s in range(1, S):
        total = (cost[nbr][..., None] + (move if may_turn[s] else held_still) + jumped[s - 1]).reshape(C, K * B, B)
        arg = np.argmin(total, axis=1)  # (C, B')
        cost = total[turn_rows, arg, branch_cols] + node[:, s]  # the minima (take_along_axis's values)
        back[s] = arg
    c, b = np.unravel_index(int(np.argmin(cost)), cost.shape)
    cs, bs = np.empty(S, int), np.empty(S, int)
    for s in range(S - 1, -1, -1):
        cs[s], bs[s] = c, b
        if s:
            k, b = divmod(int(back[s, c, b]), B)
            c = int(nbr[c, k])
    return cs, bs


def _segment_points(solver: ViperXBatchIK, base: BasePose, q: np.ndarray, k: int = 5) -> np.ndarray:
    """(..., 2k, 3) points along the elbow -> wrist -> pinch segments of joints q (..., 6)."""
    p = solver.points(base, q)
    u = np.linspace(0.0, 1.0, k)[:, None]
    elbow, wrist, pinch = (p[n][..., None, :] for n in ("elbow", "wrist", "pinch"))
    return np.concatenate([elbow + u * (wrist - elbow), wrist + u * (pinch - wrist)], axis=-2)


def _hand_points(P: np.ndarray, reach: float) -> np.ndarray:
    """(..., 6, 3) points of an open hand at pinch poses P (..., 4, 4): the pinch point, the two fingertips
    (HAND_SPREAD to each side along the closing axis), the wrist centre `reach` behind along the approach
    axis, and the palm's two sides half-way."""
    pinch, x, z = P[..., :3, 3], P[..., :3, 0], P[..., :3, 2]
    palm = pinch - 0.5 * reach * z
    return np.stack([pinch, pinch + HAND_SPREAD * x, pinch - HAND_SPREAD * x, pinch - reach * z,
                     palm + 0.5 * HAND_SPREAD * x, palm - 0.5 * HAND_SPREAD * x], axis=-2)


def _gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest distance between point sets a (..., P, 3) and b (..., Q, 3) (broadcast over ...). The squares
    summed x, y, z in that order, as np.linalg.norm sums them, coordinate by coordinate (numpy's reduction over a
    short last axis costs ten times more), and the root taken of the smallest (the root keeps the order)."""
    sq = None
    for k in range(3):
        d = a[..., :, None, k] - b[..., None, :, k]
        d *= d
        sq = d if sq is None else np.add(sq, d, out=sq)
    return np.sqrt(sq.reshape(sq.shape[:-2] + (sq.shape[-2] * sq.shape[-1],)).min(axis=-1))


def _keep_apart(good: np.ndarray, segments: np.ndarray, hands: np.ndarray,
                avoid: tuple[np.ndarray, np.ndarray]) -> None:
    """good (C, S, B) cleared in place where the arm's segment points (C, S, B, P1, 3) or its hand's points
    (C, S, P2, 3) come closer than avoid[1] (S,) to the other arm's points avoid[0] (S, P, 3) (NaN where that arm
    is out of its window: nothing to keep apart from). The segments' distances are taken only for states still
    followed at samples where the other arm is in its window (the others stay as they are): the same
    distances, element by element, as over every state."""
    pts, need = avoid
    with np.errstate(invalid="ignore"):
        good &= ~(_gap(hands, pts[None]) < need[None])[..., None]
        c, s, b = np.nonzero(good & np.isfinite(pts).all(axis=(1, 2))[None, :, None])
        good[c, s, b] = ~(_gap(segments[c, s, b], pts[s]) < need[s])


def _states(solver: ViperXBatchIK, base: BasePose, w: _Window, turns: np.ndarray, flip: bool) -> tuple:
    """(flip, P (C, S, 4, 4) the pinch poses of each turn at the samples, the closed form's solution of them,
    followed (C, S, B): the states within reach and range, the wrist and the fingertips above the table)."""
    if w.obj is not None and np.any(turns):
        # every turn at once (the same products, matrix by matrix); the demonstrated grasp (turn 0) as it is
        P = turn_grasp(w.hand[None], w.obj[None], turns[:, None], flip)  # (C, S, 4, 4)
        P[turns == 0] = turn_grasp(w.hand, w.obj, 0.0, flip)
    else:
        P = np.stack([turn_grasp(w.hand, w.obj, t, flip) for t in turns])
    sol = solver.solve(base, P[..., :3, 3], P[..., :3, :3])
    good = sol.closes & (sol.margin > MIN_MARGIN)
    good &= solver.wrist(base, sol.q)[..., 2] > WRIST_ABOVE_TABLE
    # a grasp whose fingers would have to be raised off the demonstrated pose is not the same grasp
    good &= (w.lowest(P) > -LIFT_TOLERANCE)[..., None]
    return flip, P, sol, good


def _paths(solver: ViperXBatchIK, base: BasePose, ready: np.ndarray, speed: np.ndarray, w: _Window,
           avoid: tuple[np.ndarray, np.ndarray] | None = None) -> list[_Path]:
    """The arm's best path for each half-turn of the gripper, best first. avoid: (points (S, P, 3) of the other
    arm at the samples (NaN where it is not in its window), the gap (S,) to keep from them)."""
    turns = grasp_turns(w.symmetry) if w.obj is not None else np.zeros(1)
    max_step = np.radians(TURN_STEP_MAX_DEG) if w.obj is not None and w.symmetry == 0 else 0.0
    if w.states is None:
        w.states = [_states(solver, base, w, turns, flip) for flip in (False, True)]
    out = []
    for flip, P, sol, good in w.states:
        q = sol.q  # (C, S, B, 6)
        if avoid is not None:
            good = good.copy()
            _keep_apart(good, _segment_points(solver, base, q), _hand_points(P, solver.g.wrist_to_pinch), avoid)
        live = np.flatnonzero(good.any(axis=(0, 1)))  # branches followed somewhere (the others only cost BAD)
        live = live if len(live) else np.arange(good.shape[2])
        transit0 = (np.abs(q[:, 0] - ready) / speed).max(axis=-1)  # (C, B)
        start = TRANSIT_WEIGHT * transit0 + TURN_WEIGHT * np.abs(turns)[:, None]
        jumps = np.minimum(JUMP, JUMP_PER_STEP * np.diff(w.steps, prepend=w.steps[0]))
        cs, bl = _best_path(q[:, :, live], good[:, :, live], sol.margin[:, :, live], turns, start[:, live], max_step,
                            w.may_turn, jumps)
        bs, idx = live[bl], np.arange(len(w.steps))
        followed = good[cs, idx, bs]
        followed[1:] &= np.abs(np.diff(q[cs, idx, bs], axis=0)).max(axis=-1) < jumps[1:]  # the path forced to jump
        feasible = bool(followed.all())
        low = float(sol.margin[cs, idx, bs].min())
        turn = np.unwrap(turns[cs])
        score = (10.0 + min(low, MARGIN_CAP) - TRANSIT_WEIGHT * transit0[cs[0], bs[0]] if feasible
                 else float(np.argmin(followed)) / len(idx)) - TURN_WEIGHT * float(np.abs(turn).mean())
        out.append(_Path(flip, turn, q[cs, idx, bs], P[cs, idx], score, feasible, low, len(turns) * 2))
    return sorted(out, key=lambda p: -p.score)


def _points_at(solver, base, w: _Window, path: _Path, steps: np.ndarray) -> np.ndarray:
    """(len(steps), P, 3) the arm's forearm segments (its track interpolated) and its hand's points (at the
    nearest sample) at other steps; NaN outside its window."""
    q = np.stack([np.interp(steps, w.steps, path.q[:, j]) for j in range(6)], axis=-1)
    near = np.abs(steps[:, None] - w.steps[None]).argmin(axis=1)
    pts = np.concatenate([_segment_points(solver, base, q), _hand_points(path.poses[near], solver.g.wrist_to_pinch)],
                         axis=-2)
    pts[(steps < w.steps[0]) | (steps > w.steps[-1])] = np.nan
    return pts


def _demonstrated_gap(solver: ViperXBatchIK, hand: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(S,) the distance between the two hands' points (_hand_points) as demonstrated (hand (T, 2, 4, 4))."""
    pts = _hand_points(hand[steps], solver.g.wrist_to_pinch)  # (S, 2, 6, 3)
    return _gap(pts[:, 0], pts[:, 1])


def _pair_ok(solver, bases, wins, paths, gap_needed) -> bool:
    """The two arms' chosen paths keep the gap wherever both windows run."""
    w0, w1 = wins
    common = np.union1d(w0.steps, w1.steps)
    common = common[(common >= max(w0.steps[0], w1.steps[0])) & (common <= min(w0.steps[-1], w1.steps[-1]))]
    if not len(common):
        return True
    a = _points_at(solver, bases[0], w0, paths[0], common)
    b = _points_at(solver, bases[1], w1, paths[1], common)
    return bool((_gap(a, b) >= gap_needed(common)).all())


def choose_grasps(solver: ViperXBatchIK, bases: tuple[BasePose, BasePose], ready: np.ndarray, speed: np.ndarray,
                  hand: np.ndarray, closed: np.ndarray, objs: np.ndarray, held: np.ndarray, symmetries: np.ndarray,
                  windows: np.ndarray, lowest: Callable[[int, np.ndarray, np.ndarray], np.ndarray],
                  widths: np.ndarray | None = None, turn_held_min_width: float = 0.0) -> Choice:
    """Each arm's grasp (see the module docstring). hand (T, 2, 4, 4) demonstrated pinch poses; closed (T, 2) the
    hands closed; objs (T, n_obj, 4, 4) the objects as demonstrated (retarget.object_trajectories); held (2,)
    the object each arm's window holds (-1 none); symmetries (n_obj,); windows (2, 2) [start, end); ready,
    speed (12,) both arms' joints; lowest(arm, steps, poses (C, S, 4, 4)) -> (C, S) the fingertips' height
    above the table less the clearance they keep; widths (n_obj,) the objects' grasp widths: an object
    narrower than turn_held_min_width keeps its turn while held (a hand whose pads let a thin handle roll)."""
    wins: list[_Window | None] = [None, None]
    for a in range(2):
        w0, w1 = (int(v) for v in windows[a])
        if w1 <= w0:
            continue
        steps = np.unique(np.linspace(w0, w1 - 1, min(SAMPLES, w1 - w0)).round().astype(int))
        o = int(held[a])
        run = np.zeros(len(closed), int)  # steps the hand has been closed for
        for t in range(len(closed)):
            run[t] = run[t - 1] + 1 if closed[t, a] and t else int(closed[t, a])
        thin = o >= 0 and widths is not None and widths[o] < turn_held_min_width
        settled = (run[steps] > GRIP_SETTLE_STEPS) & (not thin)
        wins[a] = _Window(a, steps, hand[steps, a], objs[steps, o] if o >= 0 else None,
                          int(symmetries[o]) if o >= 0 else 1, np.concatenate([[False], settled[1:] & settled[:-1]]),
                          lambda P, a=a, steps=steps: lowest(a, steps, P))
    arm = [slice(0, 6), slice(6, 12)]
    paths = [None if w is None else _paths(solver, bases[w.arm], ready[arm[w.arm]], speed[arm[w.arm]], w)[0]
             for w in wins]
    if wins[0] is not None and wins[1] is not None:
        def gap_needed(steps):
            return np.minimum(ARM_GAP, _demonstrated_gap(solver, hand, steps) - 0.01)

        if not _pair_ok(solver, bases, wins, paths, gap_needed):
            best = paths
            for first in (0, 1):  # the other arm chosen again around this one
                second = 1 - first
                ws = wins[second]
                avoid = (_points_at(solver, bases[first], wins[first], paths[first], ws.steps), gap_needed(ws.steps))
                redo = _paths(solver, bases[second], ready[arm[second]], speed[arm[second]], ws, avoid)[0]
                pair = [paths[0], paths[1]]
                pair[second] = redo
                if redo.feasible and _pair_ok(solver, bases, wins, pair, gap_needed) and (
                        best is paths or redo.score + pair[first].score > best[0].score + best[1].score):
                    best = pair
            paths = best
    out = np.array(hand, float)
    choices, tracks = [], []
    for a in range(2):
        w, p = wins[a], paths[a]
        o = int(held[a])
        if w is None:
            choices.append(GraspChoice(a, o, 0.0, False, np.nan, True, 0))
            tracks.append(None)
            continue
        w0, w1 = (int(v) for v in windows[a])
        turn = np.interp(np.arange(w0, w1), w.steps, p.turn)  # the sampled turns, eased between samples
        out[w0:w1, a] = turn_grasp(hand[w0:w1, a], objs[w0:w1, o] if o >= 0 else None, turn, p.flip)
        choices.append(GraspChoice(a, o, float(turn[0]), p.flip, p.margin, p.feasible, p.candidates,
                                   float(np.ptp(turn))))
        tracks.append((w.steps, p.q))
    return Choice(out, (choices[0], choices[1]), (tracks[0], tracks[1]))


__all__ = ["Choice", "GraspChoice", "choose_grasps"]
