"""What two arms execute of a demonstrated episode: their own start, joint-space transits, the skill
segments' poses as recorded, and a time-scaling their servos can follow.

    motion = plan_arm_motion(ik, actions, keypoints0, keypoint_object, fps=30.0, ready=ready_q)
    motion.q          # (m, 12) joint angles at the episode's fps: what the arms run
    motion.poses      # (m, 2, 8) the pinch poses they reach (forward kinematics) and the gripper state
    motion.s          # (m,) the demonstrated frame of each executed frame (-1: the arms' ready pose)
    motion.time_scale # executed duration / demonstrated duration
    motion.first_failure()   # (executed frame, arm, "unreachable" | "joint_limit", detail) or None

What a researcher with two arms does with a human demonstration (MimicGen's recipe, in joint space):

1. **Segments** (lib/trajectories/segmentation.py, the thesis's motion/skill segmentation, on the
   episode's own poses and object keypoints): each arm's *window* runs from its first skill segment
   to its last (the contact-rich part, and what it carries in between), or to the episode's end if
   its gripper is still closed after it. The motion segments outside it are the person's hand coming
   from and going back to rest: the arm does not replay them.
2. **Start and transits**: both arms start at their ready pose (one frame before the demonstration's
   first); each arm moves from there to its window's first configuration along a straight line in
   joint space (a quintic time profile: at rest at both ends) over the frames before its window, and
   after a window that ends with the gripper open, back to the ready pose over the remaining frames,
   lifting off first (over a waypoint above the window's last pose; where one that touches nothing is out of
   the stretched arm's reach, over one drawn back towards its base, RETREATS). A transit into a window that would
   come too close to the table, an object (at its place at the start) or the other arm goes over a
   waypoint LIFTS above the window's first pose instead, in joint space or (where the robot has a closed
   form) down to the window on a straight line of the pinch point, or with the waist turned first at the
   ready pose's height (the hand passes high over what lies between) (checked on the robot's scene, every
   frame but the NEAR_WINDOW next to the window; the first option clear, else the one least in
   contact); the physics then checks every transit like any motion (a link in the table is
   `link_collision`).
3. **Inside the window** the arm follows the poses the robot's `retarget` hands it (for the ALOHA arms
   aloha/retargeting.py: the held object's demonstrated motion with the arm's own grasp of it) with the IK
   (lib/sim/robots/ik.py), each step started from the retargeting's joints where it gives them; without a
   retarget, from the candidate configuration nearest its ready pose, with the gripper's symmetric
   orientation (half a turn about the approach axis) where that is nearer, once for the whole window.
4. **Time-scaling** (lib/sim/robots/retiming.py): the joint trajectory over the demonstrated frames is
   slowed wherever a joint would exceed its speed limit, then sampled at the frame rate again; the
   samples between two demonstrated steps are moved onto the recorded path (the poses interpolated,
   IK from the interpolated joints) and the trajectory retimed once more, so no joint is faster than
   its servo and every executed pose inside a window lies on the recorded path. The finger commands
   (g) follow the demonstrated step each executed frame has reached.

A step of a window whose pose the IK cannot reach within 1 cm and 5 degrees fails the episode
(`unreachable`, or `joint_limit` with a joint at the end of its range), at the executed frame that
reaches it; the speed limits never fail one (they slow it down).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from demoforge.lib.geometry import matrix_to_quat, quat_slerp, quat_to_matrix

from .ik import AT_LIMIT, POSITION_TOL, ROTATION_TOL_DEG, ArmsIK, IKSolution
from .retiming import at, max_speed_ratio, step_of, velocity_limited
from demoforge.lib.trajectories.segmentation import segment_trajectory

#: m of the hand's path before its first skill segment (and after its last) that the arm follows as
#: recorded: the approach into a grasp, so that the joint-space transit ends clear of the object
APPROACH = 0.10
CARTESIAN_JUMP = 0.5  # rad a joint may move between two frames of a Cartesian transit (more: the branch changes)
ON_PATH_ROUNDS = 3  # rounds of moving the samples between steps onto the path and retiming
NEAR_WINDOW = 3  # frames of a transit next to its window that the collision check leaves out
LIFTS = (0.10, 0.20, 0.30, 0.40)  # m: how much higher a transit's waypoint is when the straight transit touches something
RETREATS = ((0.10, 0.05), (0.15, 0.10), (0.20, 0.0))  # m (back, up): waypoints of a transit out of a window


@dataclass
class ArmMotion:
    """See the module docstring. sample_position_error (m) / sample_rotation_error (degrees): the worst
    residual of the executed samples between two demonstrated steps (0 when nothing was slowed)."""
    q: np.ndarray
    poses: np.ndarray
    s: np.ndarray
    ik: IKSolution
    windows: np.ndarray
    time_scale: float
    sample_position_error: float = 0.0
    sample_rotation_error: float = 0.0
    sample_failure: tuple[int, int, str, str] | None = None  # (executed frame, arm, failure, detail)
    targets: np.ndarray | None = None  # (n, 2, 8) the demonstrated poses the windows follow (after retargeting)
    grasps: Any = None  # what the retargeting chose (e.g. aloha/grasp_choice.py GraspChoice per arm)

    def first_failure(self) -> tuple[int, int, str, str] | None:
        """(executed frame, arm, failure, detail): the first followed step (or sample between steps) off
        its pose, at the executed frame that reaches it."""
        first = self.ik.first_failure()
        out = None
        if first is not None:
            t, arm, failure, detail = first
            # the first pose of its window out of reach: the arm does not set off towards it (frame 0)
            frame = 0 if t <= self.windows[arm, 0] else int(np.searchsorted(self.s, t - 1e-9))
            out = (frame, arm, failure, detail)
        if self.sample_failure is not None and (out is None or self.sample_failure[0] < out[0]):
            out = self.sample_failure
        return out

    def summary(self) -> dict:
        """Per-episode figures for the results table."""
        ik = self.ik.summary()
        return {"ik_position_error_m": max(ik["ik_position_error_m"], self.sample_position_error),
                "ik_rotation_error_deg": max(ik["ik_rotation_error_deg"], self.sample_rotation_error),
                "reachable": ik["reachable"] and self.sample_failure is None,
                "time_scale": float(self.time_scale)}


def follow_windows(actions: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray,
                   approach: float = APPROACH) -> np.ndarray:
    """(2, 2) [start, end) of each arm's window: from its first skill segment to the end of its last (or
    to the episode's end when its gripper is closed after that), grown by the last `approach` metres of
    the hand's path into it and the first out of it; (n, n) for an arm without a skill segment and
    never closed (it stays at its ready pose)."""
    actions = np.asarray(actions, float)
    n = len(actions)
    segs = segment_trajectory(actions, np.asarray(keypoints0, float), np.asarray(keypoint_object, int))
    out = np.full((2, 2), n, int)
    for arm in range(2):
        skills = [s for s in segs if s.arm == arm and s.kind == "skill"]
        closed = np.flatnonzero(actions[:, arm, 7] < 0.5)
        if not skills and not len(closed):
            continue
        start = min([s.start for s in skills] + ([int(closed[0])] if len(closed) else []))
        end = min(max([s.end for s in skills] + [start + 1]), n)
        if len(closed) and closed[-1] >= end:
            end = n
        path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(actions[:, arm, :3], axis=0), axis=1))])
        start = int(np.searchsorted(path, path[start] - approach, side="left"))
        end = int(np.searchsorted(path, path[end - 1] + approach, side="right"))
        out[arm] = start, min(end, n)
    return out


def quintic(tau: np.ndarray) -> np.ndarray:
    """The minimum-jerk profile 10 t^3 - 15 t^4 + 6 t^5: 0 to 1, at rest at both ends."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)


def _legs(q_from: np.ndarray, q_to: np.ndarray, k: int, via: np.ndarray | None = None) -> np.ndarray:
    """(k + 1, d) joints from q_from to q_to along straight lines in joint space with a quintic profile
    each (through `via` at the middle frame, at rest there, when given)."""
    if via is None:
        return q_from + (q_to - q_from) * quintic(np.arange(k + 1) / max(k, 1))[:, None]
    h = max(k // 2, 1)
    return np.concatenate([_legs(q_from, via, h), _legs(via, q_to, k - h)[1:]]) if k > 1 else _legs(q_from, q_to, k)


def _through(points: list[np.ndarray], k: int) -> np.ndarray:
    """(k + 1, d) joints along straight lines in joint space through `points`, the k frames shared evenly
    among the legs, each with a quintic profile (at rest at every point)."""
    ends = np.linspace(0, k, len(points)).round().astype(int)
    legs = [_legs(p, q, int(e1 - e0)) for p, q, e0, e1 in zip(points, points[1:], ends, ends[1:])]
    return np.concatenate([legs[0], *(leg[1:] for leg in legs[1:])])


def _lifted(ik: ArmsIK, arm: int, q: np.ndarray, lift: float, back: float = 0.0) -> np.ndarray | None:
    """The arm's joints (d,) with its pinch pose at configuration q (nq,) raised by `lift` metres (and drawn
    `back` metres horizontally towards the arm's base), nearest q (None when the arm cannot reach it)."""
    pos, R = ik.fk(q[None])
    towards = ik.base_xy[arm] - pos[0, arm, :2]
    towards *= back / max(float(np.linalg.norm(towards)), 1e-9)
    pose = np.concatenate([pos[0, arm] + [*towards, lift], matrix_to_quat(R[0, arm])])
    dofs = ik.arm_dofs[arm]
    for cand, _, ok in ik.candidates(arm, pose, q[dofs], symmetric=False):
        return cand if ok else None
    return None


def _cartesian_legs(ik: ArmsIK, arm: int, q_full: np.ndarray, q_from: np.ndarray, q_to: np.ndarray, k: int,
                    via: np.ndarray, entry: bool) -> np.ndarray | None:
    """(k + 1, d) joints of a transit through `via`, the pre-grasp configuration above the window's end of it
    (_lifted: its pinch pose raised, on the window's IK branch): a joint-space leg between that and the ready pose,
    and a straight line of the pinch point between it and the window (the descent into a grasp, the lift
    off after a release), solved by the arm's closed form on the branch nearest the joint-space line; each
    leg with a quintic profile. None when the straight leg leaves the joints' ranges or changes branch."""
    dofs = ik.arm_dofs[arm]
    near_q = q_to if entry else q_from
    h = max(k // 2, 1)
    straight_k = k - h if entry else h
    ends = np.tile(q_full, (2, 1))
    ends[0, dofs], ends[1, dofs] = via, near_q
    pos, R = ik.fk(ends)
    u = quintic(np.arange(straight_k + 1) / max(straight_k, 1))
    if not entry:
        u = u[::-1]  # from the window's end up to the pre-grasp
    path = pos[0, arm] + u[:, None] * (pos[1, arm] - pos[0, arm])
    q = ik.analytic(arm, path, np.repeat(R[1:, arm], len(u), axis=0), via + u[:, None] * (near_q - via))
    if not ((q >= ik.lower[dofs]) & (q <= ik.upper[dofs])).all() or np.abs(np.diff(q, axis=0)).max(initial=0.0) > CARTESIAN_JUMP:
        return None
    if entry:
        return np.concatenate([_legs(q_from, via, h), q[1:]])
    return np.concatenate([q, _legs(via, q_to, k - h)[1:]])


def _transit_options(ik: ArmsIK, a: int, first_end: np.ndarray, q_from: np.ndarray, q_to: np.ndarray, k: int,
                     entry: bool):
    """The transits _with_transits weighs, in its order of preference: the straight one (into a window), over
    each waypoint LIFTS higher in joint space, then with the straight line of the pinch point (the robot's closed
    form); out of a window, then the straight one if no lifted waypoint is reachable, and over each waypoint drawn
    back towards the arm's base (RETREATS); last, over each lifted waypoint with the waist turned first at the
    ready pose's height (in: before the waypoint; out: after it). first_end (2, nq): the ready frame's joints and
    those at the window's end of the transit. Generated one at a time: the first clear one ends the search, and
    a waypoint (mink's IK from every seed) is solved only when an option needs it."""
    if entry:
        yield _legs(q_from, q_to, k)
    vias = []
    for lift in LIFTS:
        via = _lifted(ik, a, first_end[1], lift)
        if via is not None:
            vias.append(via)
            yield _legs(q_from, q_to, k, via)
    if ik.analytic is not None:
        for via in vias:
            path = _cartesian_legs(ik, a, first_end[0], q_from, q_to, k, via, entry)
            if path is not None:
                yield path
    if not entry:
        if not vias:
            yield _legs(q_from, q_to, k)
        # an arm stretched out cannot lift its hand as it is: it draws back towards its base first
        for back, lift in RETREATS:
            via = _lifted(ik, a, first_end[1], lift, back)
            if via is not None:
                yield _legs(q_from, q_to, k, via)
    # the waist turned at the ready pose's height, so the hand passes high over what lies between
    ready = q_from if entry else q_to
    for via in vias:
        turned = ready.copy()
        turned[0] = via[0]
        yield _through([q_from, turned, via, q_to] if entry else [q_from, via, turned, q_to], k)


def _with_transits(ik: ArmsIK, sol: IKSolution, windows: np.ndarray, ready: np.ndarray,
                   collides: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray:
    """(n + 1, nq) joints over the ready frame and the n demonstrated frames: each arm's window as the IK
    follows it, joint-space transits from the ready pose into it and from its end back to the ready pose.
    `collides` (rows (k, nq) -> (k, 2) bool: an arm comes too close to something) checks each transit,
    except its `NEAR_WINDOW` frames next to the window (the window's own pose is next to its object). One
    into a window that touches something goes over a waypoint above the window's first pose (LIFTS higher:
    the first that touches nothing, else the one that touches least); one out of a window always does (the
    objects have moved since the start, so the check knows less there: the arm lifts off what it released
    before it turns away)."""
    n = len(sol.q)
    Q = np.empty((n + 1, sol.q.shape[1]))
    Q[0], Q[1:] = ready, sol.q
    for a, dofs in enumerate(ik.arm_dofs):
        w0, w1 = (int(v) for v in windows[a])
        if w1 <= w0:
            Q[:, dofs] = ready[dofs]
            continue
        # rows: the ready frame .. the window's first step (row w0 + 1); the window's last step (row w1) .. row n
        for rows, q_from, q_to, end, entry in ((np.arange(w0 + 2), ready[dofs], sol.q[w0, dofs], w0 + 1, True),
                                               (np.arange(w1, n + 1), sol.q[w1 - 1, dofs], ready[dofs], w1, False)):
            if len(rows) < 2:
                continue
            checked = rows[:-NEAR_WINDOW] if entry else rows[NEAR_WINDOW:]

            def touches(path: np.ndarray) -> int:
                if collides is None or not len(checked):
                    return 0
                Q[rows[:, None], dofs] = path
                return int(collides(Q[checked])[:, a].sum())

            best, least = None, None
            # the rows as they are before touches() writes options into them (they are the waypoints' starts)
            for path in _transit_options(ik, a, Q[[0, end]], q_from, q_to, len(rows) - 1, entry):
                k = touches(path)
                if least is None or k < least:
                    best, least = path, k
                if k == 0:
                    break
            Q[rows[:, None], dofs] = best
    return Q


def _path_at(poses: np.ndarray, sol: IKSolution, s_demo: np.ndarray, stop: int):
    """The followed path at fractional demonstrated steps s_demo (m,) before step `stop`: (active (m, 2) the
    samples that lie between two followed steps, pos (m, 2, 3), quat (m, 2, 4) xyzw) with the pose
    interpolated (position linear, rotation slerp, in the orientation the arm follows); None when none does."""
    f0 = np.floor(s_demo + 1e-9).astype(int)
    frac = s_demo - f0
    between = (frac > 1e-9) & (f0 >= 0) & (f0 + 1 < min(len(poses), stop + 1))
    f0c = np.clip(f0, 0, len(poses) - 2)
    active = between[:, None] & sol.followed[f0c] & sol.followed[f0c + 1]
    if not active.any():
        return None
    xyzw = poses[..., 3:7] / np.linalg.norm(poses[..., 3:7], axis=-1, keepdims=True)
    for a in range(2):
        if sol.flipped[a]:
            x, y, z, w_ = np.moveaxis(xyzw[:, a], -1, 0)
            xyzw[:, a] = np.stack([y, -x, w_, -z], axis=-1)  # q * (0, 0, 1, 0): half a turn about its own z
    w = frac[:, None]
    pos = (1 - w[..., None]) * poses[f0c, :, :3] + w[..., None] * poses[f0c + 1, :, :3]
    return active, pos, quat_slerp(xyzw[f0c], xyzw[f0c + 1], np.repeat(w, 2, axis=1))


def _on_path(ik: ArmsIK, q: np.ndarray, s_demo: np.ndarray, poses: np.ndarray, sol: IKSolution, fps: float,
             stop: int) -> np.ndarray:
    """The executed samples between two followed steps (before step `stop`) moved onto the recorded path
    (_path_at)."""
    path = _path_at(poses, sol, s_demo, stop)
    if path is None:
        return q
    active, pos, quat = path
    R = quat_to_matrix(quat)
    rows = np.flatnonzero(active.any(axis=1))
    out = q.copy()
    out[rows] = ik.refine(q[rows], pos[rows], R[rows], quat[rows][..., [3, 0, 1, 2]], active[rows], fps)[0]
    # near the wrist's singularity the closed form's nearest branch can differ from sample to sample: where a
    # joint jumps between neighbouring samples, those samples are refined from the interpolated joints alone
    step = np.abs(np.diff(out, axis=0)).max(axis=1)
    jumped = np.zeros(len(out), bool)
    jumped[1:] |= step > CARTESIAN_JUMP
    jumped[:-1] |= step > CARTESIAN_JUMP
    r = rows[jumped[rows]]
    if len(r):
        out[r] = ik.refine(q[r], pos[r], R[r], quat[r][..., [3, 0, 1, 2]], active[r], fps, analytic=False)[0]
    return out


def _off_path(ik: ArmsIK, q: np.ndarray, pos: np.ndarray, R: np.ndarray, s_demo: np.ndarray, poses: np.ndarray,
              sol: IKSolution, stop: int):
    """(the first executed frame off its path as ArmMotion.sample_failure or None, the worst position (m) and
    rotation (degrees) error) of the executed frames between two followed steps, as they are finally run."""
    path = _path_at(poses, sol, s_demo, stop)
    if path is None:
        return None, 0.0, 0.0
    active, want, quat = path
    pe = np.where(active, np.linalg.norm(pos - want, axis=-1), 0.0)
    c = (np.einsum("maij,maij->ma", R, quat_to_matrix(quat)) - 1.0) / 2.0
    re = np.where(active, np.degrees(np.arccos(np.clip(c, -1.0, 1.0))), 0.0)
    bad = (pe > POSITION_TOL) | (re > ROTATION_TOL_DEG)
    if not bad.any():
        return None, float(pe.max()), float(re.max())
    i = int(np.argmax(bad.any(axis=1)))
    arm = int(np.argmax(bad[i]))
    dofs = ik.arm_dofs[arm]
    limited = bool(((q[i, dofs] - ik.lower[dofs] < AT_LIMIT) | (ik.upper[dofs] - q[i, dofs] < AT_LIMIT)).any())
    t = int(np.floor(s_demo[i]))
    failure = (i, arm, "joint_limit" if limited else "unreachable",
               f"arm {arm} ends {pe[i, arm] * 1000:.0f} mm and {re[i, arm]:.1f} deg from its path between steps {t} and "
               f"{t + 1} ({'a joint at the end of its range' if limited else 'no joint at a limit'}; tolerance "
               f"{POSITION_TOL * 1000:.0f} mm, {ROTATION_TOL_DEG:g} deg)")
    return failure, float(pe.max()), float(re.max())


def plan_arm_motion(ik: ArmsIK, actions: np.ndarray, keypoints0: np.ndarray, keypoint_object: np.ndarray,
                    fps: float = 30.0, ready: np.ndarray | None = None, until_failure: bool = False,
                    collides: Callable[[np.ndarray], np.ndarray] | None = None,
                    retarget: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, Any]] | None = None) -> ArmMotion:
    """The arms' motion for an episode's (n, 2, 8) actions (see the module docstring). until_failure: the
    IK stops at the first step off its target (the simulation stops there); collides: the transits'
    check against the scene at its start (joints (k, nq) -> (k, 2) bool per arm), None: no check;
    retarget: (actions, windows) -> (the (n, 2, 8) poses the arms follow instead, what it chose), e.g. each
    window's grasp turned about the held object's axis (retarget.py); what it chose may carry `joints`
    ((n, nq) the IK's starting point at each step); None: the gripper's half-turn where that is nearer, as
    the IK finds it."""
    actions = np.asarray(actions, float)
    n = len(actions)
    ready = ik.rest if ready is None else np.asarray(ready, float)
    windows = follow_windows(actions, keypoints0, keypoint_object)
    grasps = None
    if retarget is not None:
        actions, grasps = retarget(actions, windows)
    sol = ik.follow(actions, windows, fps, until_failure, reference=ready, symmetric=retarget is None,
                    guess=getattr(grasps, "joints", None))
    Q = _with_transits(ik, sol, windows, ready, collides)
    r = velocity_limited(Q, fps, ik.speed)
    s_demo = r.s - 1.0
    q = at(Q, r.s)
    first = sol.first_failure()
    stop = n if first is None else first[0]
    for _ in range(ON_PATH_ROUNDS):
        q = _on_path(ik, q, s_demo, actions, sol, fps, stop)
        if max_speed_ratio(q, fps, ik.speed) <= 1.0 + 1e-9:
            break
        # the samples moved onto the path made a joint too fast: retime, and the new samples go onto the path too
        r2 = velocity_limited(q, fps, ik.speed)
        q, s_demo = at(q, r2.s), at(s_demo, r2.s)
    pos, R = ik.fk(q)
    # checked as finally run: the second retiming interpolates again between the samples moved onto the path
    sample_failure, spe, sre = _off_path(ik, q, pos, R, s_demo, actions, sol, stop)
    g = actions[np.clip(step_of(s_demo), 0, n - 1), :, 7]
    poses = np.concatenate([pos, matrix_to_quat(R), g[..., None]], axis=-1)
    scale = (len(q) - 1) / max(n - 1, 1)
    return ArmMotion(q, poses, s_demo, sol, windows, float(scale), spe, sre, sample_failure, actions, grasps)
