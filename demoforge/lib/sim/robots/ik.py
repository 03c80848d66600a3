"""Inverse kinematics of two arms along an episode, with mink (differential IK on MuJoCo, a QP per step).

    ik = ArmsIK(xml, assets, sites=("left_hand_pinch", "right_hand_pinch"), arm_joints=(range(6), range(6, 12)),
                speed=speed_limits, arm_seeds=seed_fn, rest=rest_q)
    sol = ik.solve(actions)          # (n, 2, 8) gripper poses -> sol.q (n, 12), residuals per step
    sol = ik.follow(actions, windows, reference=ready_q, symmetric=True)   # each arm only inside its window
    sol.first_failure(0.01, 5.0)     # (step, arm, "unreachable" | "joint_limit", detail) or None

One MuJoCo model holds both arms (only their joints: the hands' fingers do not move the pinch sites),
and each QP solves both arms' pose tasks together (one 12-dof problem per iteration, not two 6-dof
ones: the QP costs about the same, the Python around it half). An arm outside its window (`follow`:
the steps it follows, a transit planned in joint space elsewhere) is held: its task's target is its
own pose, so the QP leaves it. Along the window the solution is warm-started: each step starts from
the previous step's joints moved on with their last velocity, so at 30 fps one iteration usually
lands within 0.5 mm and 0.25 degrees of the target (no QP at all), and at most `iterations` are spent
per step, while each brings the arm closer. Each iteration is mink's QP (mink.build_ik: the tasks'
weighted residuals and the configuration limits) solved by DAQP as qpsolvers does (ik_qp.py: the same
arithmetic without their per-call Python layers). mink's
ConfigurationLimit keeps every joint inside its range. There is no speed limit here: the IK solves
for the path, and lib/sim/robots/retiming.py then slows down whatever a joint cannot follow at the
demonstrated speed.

Where an arm's window starts, its joints come from candidates: the arm's closed-form geometric
solutions for that pose (`arm_seeds`: elbow up and down, both branches of a roll-pitch-roll wrist)
and, with `symmetric`, for the pose turned 180 degrees about the approach axis (a two-finger parallel
gripper grasps the same way turned half a turn: lib/sim/gripper.py and aloha/model.py build both
hands mirror-symmetric about that axis), each refined by mink; they are tried nearest first, nearest
meaning the shortest joint-space transit from the `reference` configuration (the slowest joint's
travel time). The chosen orientation holds for the whole window (no half-turn mid-grasp). When an
arm fails a step of its window, the window is tracked again from its next candidate, and the arm
keeps the candidate that follows furthest (the two arms' problems are independent: separate tasks
and joints).

A step fails when a pinch point ends more than `tol_position` metres or `tol_rotation_deg` degrees from
its target; the failure is `unreachable` when the target lies beyond the arm's reach (the robot's
`out_of_reach`: farther from the shoulder than the stretched arm) or no joint is at a limit, and
`joint_limit` when a joint of that arm is at its range's end at that step (the pose lies within
reach, but the joint cannot turn further).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np

from .ik_qp import StepQP

POSITION_TOL = 0.01  # m
ROTATION_TOL_DEG = 5.0
CONVERGED_POSITION = 1e-3  # m: stop iterating a step below this ...
CONVERGED_ROTATION = np.radians(0.5)  # ... and this (half the accuracy the tests ask of a reachable pose)
ROTATION_TOL = np.radians(ROTATION_TOL_DEG)
AT_LIMIT = 0.02  # rad from a range's end counts as at the limit (mink approaches it geometrically)
TRIES = 4  # candidates tried per arm and window
COLLISION_DETECTION = 0.05  # m: geoms closer than this enter the QP's collision constraints
ANALYTIC_NEAR = 1.5  # rad: a closed-form answer farther than this from the interpolated joints is another branch
# a start this far inside the convergence thresholds needs no QP whichever way its errors are rounded (batched
# errors may differ from _errors' in the last bits)
SETTLED = 1.0 - 1e-9
RUN = 4  # steps _track takes at once first, twice as many after each run that needs no QP


@dataclass
class IKSolution:
    """q (n, nq) joint angles per step; position_error (n, 2) m and rotation_error (n, 2) degrees of each
    arm's pinch pose after IK; at_range_limit (n, 2): a joint of the arm at the end of its range;
    iterations: QP solves in all; followed (n, 2): the steps each arm follows (the others are not IK
    targets: their residuals are 0); flipped (2,): the arm follows its poses turned 180 degrees about
    the approach axis (the gripper's symmetry)."""
    q: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    at_range_limit: np.ndarray
    iterations: int
    out_of_reach: np.ndarray | None = None  # (n, 2) the target lies beyond the stretched arm
    followed: np.ndarray | None = None
    flipped: np.ndarray = field(default_factory=lambda: np.zeros(2, bool))

    def failed_steps(self, tol_position: float = POSITION_TOL, tol_rotation_deg: float = ROTATION_TOL_DEG) -> np.ndarray:
        """(n, 2) bool: a followed step whose pose is off its target by more than the tolerances."""
        bad = (self.position_error > tol_position) | (self.rotation_error > tol_rotation_deg)
        return bad if self.followed is None else bad & self.followed

    def first_failure(self, tol_position: float = POSITION_TOL,
                      tol_rotation_deg: float = ROTATION_TOL_DEG) -> tuple[int, int, str, str] | None:
        """(step, arm, failure, detail) of the first step off its target, or None."""
        bad = self.failed_steps(tol_position, tol_rotation_deg)
        if not bad.any():
            return None
        t = int(np.argmax(bad.any(axis=1)))
        arm = int(np.argmax(bad[t]))
        far = self.out_of_reach is not None and bool(self.out_of_reach[t, arm])
        limited = not far and bool(self.at_range_limit[t, arm])
        why = ("the target beyond the arm's reach" if far else
               "a joint at the end of its range" if limited else "no joint at a limit")
        detail = (f"arm {arm} ends {self.position_error[t, arm] * 1000:.0f} mm and {self.rotation_error[t, arm]:.1f} deg "
                  f"from its pose at step {t} ({why}; tolerance {tol_position * 1000:.0f} mm, {tol_rotation_deg:g} deg)")
        return t, arm, "joint_limit" if limited else "unreachable", detail

    def summary(self) -> dict:
        """Per-episode figures: the worst residuals (m, degrees) and whether every step is within tolerance."""
        return {"ik_position_error_m": float(self.position_error.max()) if self.position_error.size else 0.0,
                "ik_rotation_error_deg": float(self.rotation_error.max()) if self.rotation_error.size else 0.0,
                "reachable": not bool(self.failed_steps().any())}


def _first_bad(bad: np.ndarray) -> int:
    """The first step of a (n,) bool mask (len when none)."""
    return int(np.argmax(bad)) if bad.any() else len(bad)


def _rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) between rotation matrices (..., 3, 3)."""
    c = (np.einsum("...ij,...ij->...", Ra, Rb) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def half_turn(R: np.ndarray, wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (..., 3, 3) and their quaternions (..., 4, wxyz) turned 180 degrees about their own z
    (the approach axis): x and y reversed; q * (0, 0, 0, 1) in wxyz is (-z, y, -x, w)."""
    R2 = R.copy()
    R2[..., :, :2] *= -1.0
    w, x, y, z = np.moveaxis(wxyz, -1, 0)
    return R2, np.stack([-z, y, -x, w], axis=-1)


def wrist_branch(q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The other wrist branch of an arm's joints (6,) for the same pinch pose: the ViperX wrist is roll-pitch-roll
    about collinear axes, so (roll + pi, -pitch, roll + pi) leaves the gripper where it is (wrapped into range)."""
    out = np.array(q, float)
    for j in (3, 5):
        v = out[j] + np.pi
        out[j] = v - 2 * np.pi if v > hi[j] else v
    out[4] = -out[4]
    return out


class ArmsIK:
    """Warm-started differential IK of two arms with mink (see the module docstring)."""

    def __init__(self, xml: str, assets: dict, sites: Sequence[str], arm_joints: Sequence[Sequence[int]],
                 speed: Sequence[float], arm_seeds: Callable[[int, np.ndarray], list[np.ndarray]], rest: np.ndarray,
                 out_of_reach: Callable[[np.ndarray], np.ndarray] | None = None, iterations: int = 8,
                 first_iterations: int = 60, position_cost: float = 1.0, orientation_cost: float = 0.15,
                 lm_damping: float = 1e-4,
                 analytic: Callable[[int, np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
                 collision_pairs: Sequence[tuple[Sequence[str], Sequence[str], float]] = (),
                 posture_cost: float = 0.0):
        import mink
        import mujoco

        self.mink, self.mujoco = mink, mujoco
        self.model = mujoco.MjModel.from_xml_string(xml, assets)
        self._kinematics = mujoco.MjData(self.model)  # _site_poses' own data: the IK's configuration stays as it is
        self.cfg = mink.Configuration(self.model)
        self.sites = np.array([self.model.site(s).id for s in sites])
        # the sites' rows of MuJoCo's arrays: a slice where they are in a row (a view, no gather each time)
        self.site_rows = (slice(int(self.sites[0]), int(self.sites[-1]) + 1) if (np.diff(self.sites) == 1).all()
                          else self.sites)
        self.site_names = list(sites)
        self.tasks = [mink.FrameTask(s, "site", position_cost=position_cost, orientation_cost=orientation_cost,
                                     lm_damping=lm_damping) for s in sites]
        self.limits = [mink.ConfigurationLimit(self.model)]
        # mink's own collision limits: (geoms, geoms, the distance they keep); pairs within COLLISION_DETECTION
        # of each other constrain each QP step (its broadphase skips the others)
        self.limits += [mink.CollisionAvoidanceLimit(self.model, [(list(a), list(b))], minimum_distance_from_collisions=d,
                                                     collision_detection_distance=COLLISION_DETECTION)
                        for a, b, d in collision_pairs]
        if posture_cost > 0:  # a pull towards the rest (ready) pose: what the arm does with what the tasks leave free
            posture = mink.PostureTask(self.model, cost=posture_cost)
            posture.set_target(np.asarray(rest, float))
            self.tasks = self.tasks + [posture]
        self.qp = StepQP(self.cfg, self.tasks, self.limits)  # mink's QP per iteration, without its Python layers
        self.arm_dofs = [np.asarray(list(j), int) for j in arm_joints]
        self.speed = np.asarray(speed, float)
        self.rest = np.asarray(rest, float)
        self.lower, self.upper = self.model.jnt_range[:, 0].copy(), self.model.jnt_range[:, 1].copy()
        self.arm_seeds, self.out_of_reach = arm_seeds, out_of_reach
        # (arm, pos (m, 3), R (m, 3, 3), near (m, 6)) -> (m, 6): the arm's exact solution nearest `near`, where
        # the robot has a closed form: refine() starts from it instead of the joints interpolated between steps
        self.analytic = analytic
        self.iterations, self.first_iterations = int(iterations), int(first_iterations)
        mujoco.mj_kinematics(self.model, self._kinematics)
        # (2, 2) each arm's first joint's place on the table: where an arm draws back to
        self.base_xy = np.array([self._kinematics.xpos[self.model.jnt_bodyid[d[0]], :2] for d in self.arm_dofs])

    # ------------------------------------------------------------------ poses
    @staticmethod
    def targets(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos (n, 2, 3), R (n, 2, 3, 3), wxyz (n, 2, 4)) of (n, 2, >= 7) poses [x y z qx qy qz qw ...]."""
        from scipy.spatial.transform import Rotation

        poses = np.asarray(poses, float)
        n = len(poses)
        xyzw = poses[..., 3:7] / np.linalg.norm(poses[..., 3:7], axis=-1, keepdims=True)
        R = Rotation.from_quat(xyzw.reshape(-1, 4)).as_matrix().reshape(n, 2, 3, 3)
        return poses[..., :3].copy(), R, xyzw[..., [3, 0, 1, 2]]

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pos (m, 2, 3), R (m, 2, 3, 3)) of the pinch sites for joint configurations q (m, nq)."""
        q = np.atleast_2d(np.asarray(q, float))
        pos, R = self._site_poses(q)
        if len(q):  # the IK's configuration left at the last one, as it always was (candidates() starts from it)
            self.cfg.update(q[-1])
        return pos, R

    def _set_targets(self, pos: np.ndarray, wxyz: np.ndarray, active: np.ndarray) -> None:
        """Targets of the active arms; an arm not active is held (its target is where it is)."""
        SE3 = self.mink.SE3
        for a in range(2):
            if active[a]:
                self.tasks[a].set_target(SE3(wxyz_xyz=np.concatenate([wxyz[a], pos[a]])))
            else:
                self.tasks[a].set_target(self.cfg.get_transform_frame_to_world(self.site_names[a], "site"))

    def _site_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pos (m, 2, 3), R (m, 2, 3, 3)) of the pinch sites for configurations q (m, nq): fk's, by MuJoCo's
        kinematics alone (what the sites' poses need) on a data of its own."""
        d, model, kinematics = self._kinematics, self.model, self.mujoco.mj_kinematics
        qpos, xpos, xmat, sites = d.qpos, d.site_xpos, d.site_xmat, self.site_rows
        pos, R = np.empty((len(q), 2, 3)), np.empty((len(q), 2, 9))
        for i, qi in enumerate(q):
            qpos[:] = qi
            kinematics(model, d)
            pos[i], R[i] = xpos[sites], xmat[sites]
        return pos, R.reshape(-1, 2, 3, 3)

    def _settled(self, q: np.ndarray, pos: np.ndarray, R: np.ndarray, active: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(settled (m,), pe (m, 2) m, re (m, 2) rad) of configurations q (m, nq) with targets pos, R (m, 2, ...):
        the rows whose active arms are all converged (SETTLED), where _iterate would stop before its first QP,
        and the errors it gives there (_errors' formulas over all rows at once; 0 for arms not active)."""
        xpos, xmat = self._site_poses(q)
        diff = xpos - pos
        pe = np.where(active, np.sqrt(np.einsum("mai,mai->ma", diff, diff)), 0.0)
        re = np.where(active, _rotation_angle(xmat, R), 0.0)
        off = np.maximum(pe / CONVERGED_POSITION, re / CONVERGED_ROTATION)
        return (off < SETTLED).all(axis=1), pe, re

    def _errors(self, pos: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.cfg.data
        diff = d.site_xpos[self.site_rows] - pos
        pe = np.sqrt(np.einsum("ai,ai->a", diff, diff))
        re = _rotation_angle(d.site_xmat[self.site_rows].reshape(2, 3, 3), R)
        return pe, re

    def _iterate(self, pos, R, wxyz, max_iter: int, dt: float, active: np.ndarray,
                 give_up: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """Up to max_iter QP steps of the active arms towards their targets from the current configuration;
        stops early once they are converged or (give_up) an iteration no longer brings the unconverged
        ones closer (an arm held by a limit or out of reach stays where it is: more iterations would only
        cost time). Errors of arms not active are 0."""
        pe, re = self._errors(pos, R)
        pe, re = np.where(active, pe, 0.0), np.where(active, re, 0.0)
        k = 0
        off = np.maximum(pe / CONVERGED_POSITION, re / CONVERGED_ROTATION)
        if (off > 1.0).any():
            self._set_targets(pos, wxyz, active)  # only when a QP is solved (the prediction often lands already)
        while k < max_iter and (off > 1.0).any():
            dq = self.qp.solve(dt)
            if dq is None:  # no step within the limits: the configuration stays
                break
            q_before = self.cfg.q.copy()
            self.cfg.integrate_inplace(dq / dt, dt)
            pe1, re1 = self._errors(pos, R)
            pe1, re1 = np.where(active, pe1, 0.0), np.where(active, re1, 0.0)
            k += 1
            off1 = np.maximum(pe1 / CONVERGED_POSITION, re1 / CONVERGED_ROTATION)
            if off1.max() > off.max() + 1.0:  # the linearisation overshot (near a singular configuration): undo
                self.cfg.update(q_before)
                break
            pe, re, before, off = pe1, re1, off, off1
            if give_up and not (off[before > 1.0] < 0.8 * before[before > 1.0]).any():
                break
        return pe, re, k

    # ------------------------------------------------------------------ candidates for a window's first pose
    def candidates(self, arm: int, pose: np.ndarray, reference: np.ndarray, symmetric: bool
                   ) -> Iterator[tuple[np.ndarray, bool, bool]]:
        """(q of the arm's joints, flipped, within tolerance) for the pose [x y z qx qy qz qw], nearest first
        (the slowest joint's travel time from `reference`, the arm's joints; a seed outside the joints'
        ranges counts its excess ten times): every seed refined by mink (until an iteration no longer brings it closer), those that converge (1 mm, 0.5 degrees)
        first, then those within tolerance (a seed held at a joint's range), then, when none is, the closest
        of the others (the arm cannot reach the pose; its residual says how far)."""
        pos, R, wxyz = self.targets(np.asarray(pose, float)[None, None].repeat(2, axis=1))
        pos, R, wxyz = pos[0], R[0], wxyz[0]
        dofs = self.arm_dofs[arm]
        lo, hi = self.lower[dofs], self.upper[dofs]
        seeds = [(np.asarray(s, float), False) for s in self.arm_seeds(arm, pose)] + [(self.rest[dofs], False)]
        if symmetric:
            R2, w2 = half_turn(R[arm], wxyz[arm])
            flipped_pose = np.concatenate([pos[arm], w2[[1, 2, 3, 0]]])
            seeds += [(np.asarray(s, float), True) for s in self.arm_seeds(arm, flipped_pose)] + [(self.rest[dofs], True)]
        seeds += [(wrist_branch(s, lo, hi), f) for s, f in seeds]

        def cost(s):
            c = np.clip(s, lo, hi)
            return float((np.abs(c - reference) / self.speed[dofs]).max() + 10.0 * np.abs(s - c).max())

        active = np.arange(2) == arm
        refined = []  # (rank: 0 converged, 1 within tolerance, 2 off; cost; q; flipped)
        for s, flipped in seeds:
            Ra, wa = (half_turn(R, wxyz) if flipped else (R, wxyz))
            q = self.cfg.q.copy()
            q[dofs] = np.clip(s, lo, hi)
            self.cfg.update(q)
            pe, re, _ = self._iterate(pos, Ra, wa, self.first_iterations, 1.0, active)
            qa = self.cfg.q[dofs].copy()
            score = max(pe[arm] / POSITION_TOL, np.degrees(re[arm]) / ROTATION_TOL_DEG)
            converged = pe[arm] <= CONVERGED_POSITION and re[arm] <= CONVERGED_ROTATION
            refined.append((0 if converged else 1 if score <= 1.0 else 2, cost(qa) if score <= 1.0 else score, qa, flipped))
        yielded = []
        for rank, _, qa, flipped in sorted(refined, key=lambda r: r[:2]):
            if rank == 2 and yielded:
                break
            if any(np.abs(qa - y).max() < 0.05 for y in yielded):
                continue
            yielded.append(qa)
            yield qa, flipped, rank < 2
            if rank == 2:
                break

    # ------------------------------------------------------------------ following the poses
    def solve(self, poses: np.ndarray, fps: float = 30.0, until_failure: bool = False) -> IKSolution:
        """Joints for every step of (n, 2, >= 7) poses [x y z qx qy qz qw ...] (world frame), each arm's
        first step from the candidate nearest the rest configuration, no symmetric turn."""
        n = len(poses)
        return self.follow(poses, np.array([[0, n], [0, n]]), fps, until_failure, self.rest, symmetric=False)

    def follow(self, poses: np.ndarray, windows: np.ndarray, fps: float = 30.0, until_failure: bool = False,
               reference: np.ndarray | None = None, symmetric: bool = True,
               guess: np.ndarray | None = None) -> IKSolution:
        """Joints for (n, 2, >= 7) poses, arm a following its poses over steps windows[a] = [start, end)
        (see the module docstring); before its window an arm is at `reference` (default: the rest
        configuration), after it it holds its last step's joints.

        until_failure: stop tracking at the first step off its target (the simulator, which stops there
        anyway, needs no more): the later steps hold that step's joints and residuals.

        guess: (n, nq) joints to start each step of a window from (e.g. the arm's closed-form solution on the
        branch a grasp choice tracked) instead of the last step's moved on with its velocity; the window's
        first step starts from it too, before any other candidate.
        """
        poses = np.asarray(poses, float)
        n = len(poses)
        targets = self.targets(poses)
        ref = self.rest if reference is None else np.asarray(reference, float)
        windows = np.asarray(windows, int)
        arms = [a for a in range(2) if windows[a, 1] > windows[a, 0]]
        self.cfg.update(ref)
        if not arms:  # neither arm follows a pose: both stay at the reference
            return IKSolution(np.tile(ref, (n, 1)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2), bool), 0,
                              followed=np.zeros((n, 2), bool))
        gens = {a: self.candidates(a, poses[windows[a, 0], a, :7], ref[self.arm_dofs[a]], symmetric) for a in arms}
        if guess is not None:
            guess = np.clip(np.asarray(guess, float), self.lower, self.upper)
        cands = {a: (guess[windows[a, 0], self.arm_dofs[a]], False, True)
                 if guess is not None and np.isfinite(guess[windows[a, 0], self.arm_dofs[a]]).all() else next(gens[a])
                 for a in arms}
        res = self._track(ref, targets, arms, windows, cands, fps, until_failure, n, guess)
        iterations = res.pop("iterations")
        tries = {a: 1 for a in arms}
        while arms:
            first = {a: res[a]["first_bad"] for a in arms}
            a = min(arms, key=lambda b: first[b])  # the arm that fails first (where the simulation stops)
            if first[a] >= n or tries[a] >= TRIES:
                break
            stop = first[a]
            while tries[a] < TRIES:  # its next candidates, alone; it keeps the one that follows furthest
                cand = next(gens[a], None)
                if cand is None:
                    tries[a] = TRIES
                    break
                tries[a] += 1
                run = self._track(ref, targets, [a], windows, {a: cand}, fps, until_failure, n)  # no guess: its own seed
                iterations += run["iterations"]
                if (run[a]["first_bad"] > res[a]["first_bad"]) if until_failure else run[a]["bad"] < res[a]["bad"]:
                    res[a], cands[a] = run[a], cand
                if run[a]["bad"] == 0:
                    break
            if not until_failure or res[a]["first_bad"] <= stop:
                if not until_failure:
                    tries[a] = TRIES
                continue
            for b in arms:  # an arm tracked only up to the old stop: on to the new one
                if b != a and res[b]["until"] <= min(res[a]["first_bad"], windows[b, 1] - 1):
                    run = self._track(ref, targets, [b], windows, {b: cands[b]}, fps, until_failure, res[a]["first_bad"] + 1,
                                      guess)
                    iterations += run["iterations"]
                    res[b] = run[b]
        sol = IKSolution(np.tile(ref, (n, 1)), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2), bool), iterations,
                         followed=np.zeros((n, 2), bool))
        for a in arms:
            dofs = self.arm_dofs[a]
            sol.followed[windows[a, 0]:windows[a, 1], a] = True
            sol.q[:, dofs], sol.flipped[a] = res[a]["q"], cands[a][1]
            sol.position_error[:, a], sol.rotation_error[:, a] = res[a]["pe"], res[a]["re"]
            sol.at_range_limit[:, a] = res[a]["range"]
        if self.out_of_reach is not None:
            sol.out_of_reach = np.asarray(self.out_of_reach(poses), bool)
        return sol

    def _track(self, ref, targets, arms, windows, cands, fps, until_failure, limit, guess=None) -> dict:
        """Warm-started IK of the given arms (the other held at `ref`) along their windows' steps, both in one
        QP where both follow: arm a enters at windows[a, 0] with its candidate cands[a] = (joints, flipped, ok)
        and follows its poses (turned half a turn if flipped) to windows[a, 1] or `limit`; with until_failure
        up to the first step off its target of any of them. Before its window an arm is at `ref`, after it
        it holds its last joints. Returns {arm: q (n, 6), pe, re (n,), range (n,), bad, first_bad, until}
        and the QP iterations."""
        pos, R, wxyz = targets
        n = len(pos)
        Rt, wt = R.copy(), wxyz.copy()
        for a in arms:
            if cands[a][1]:
                Rt[:, a], wt[:, a] = half_turn(R[:, a], wxyz[:, a])
        q = np.tile(ref, (n, 1))
        pe_all, re_all = np.zeros((n, 2)), np.zeros((n, 2))
        lo, hi = windows[:, 0].copy(), np.minimum(windows[:, 1], limit)
        follows = np.zeros(2, bool)
        follows[list(arms)] = True
        dt = 1.0 / fps
        cur = np.array(ref, float)
        iters, until = 0, n
        t0, t_end = min(lo[a] for a in arms), int(max(hi[a] for a in arms))
        run, skip, took = RUN, t0, False
        for t in range(t0, t_end):
            if t < skip:  # taken by _settled_steps
                continue
            if guess is not None:
                skip, cur = self._settled_steps(t, min(t + run, t_end), cur, guess, follows, lo, hi, (pos, Rt),
                                                (q, pe_all, re_all))
                run = 2 * run if skip == min(t + run, t_end) else RUN
                if skip > t:
                    took = True
                    continue
            active = follows & (lo <= t) & (t < hi)
            if not active.any():
                q[t] = cur
                continue
            for a in np.flatnonzero(active):
                dofs = self.arm_dofs[a]
                if t == lo[a]:
                    cur[dofs] = cands[a][0]
                elif guess is not None and np.isfinite(guess[t, dofs]).all():
                    cur[dofs] = guess[t, dofs]
                elif t >= lo[a] + 2:  # predict: the joints keep their last step's velocity (within range)
                    cur[dofs] = np.clip(2 * q[t - 1, dofs] - q[t - 2, dofs], self.lower[dofs], self.upper[dofs])
            self.cfg.update(cur)
            pe, re, k = self._iterate(pos[t], Rt[t], wt[t], self.first_iterations if (t == lo).any() else self.iterations,
                                      dt, active)
            iters += k
            off = active & ((pe > POSITION_TOL) | (re > ROTATION_TOL)) & (t > lo)
            newly = off & (pe_all[t - 1] <= POSITION_TOL) & (re_all[t - 1] <= ROTATION_TOL)
            if newly.any():
                # newly off its target: again from the last step's joints, without the prediction and without
                # giving up early (near a singular configuration the extrapolated velocity overshoots)
                cur = self.cfg.q.copy()
                for a in np.flatnonzero(newly):
                    cur[self.arm_dofs[a]] = q[t - 1, self.arm_dofs[a]]
                self.cfg.update(cur)
                pe2, re2, k = self._iterate(pos[t], Rt[t], wt[t], self.first_iterations, dt, newly, give_up=False)
                iters += k
                pe, re = np.where(newly, pe2, pe), np.where(newly, re2, re)
            cur = self.cfg.q.copy()
            q[t], pe_all[t], re_all[t] = cur, pe, re
            if until_failure and (active & ((pe > POSITION_TOL) | (re > ROTATION_TOL))).any():
                until = t + 1
                break
        if took:  # the configuration where the loop leaves it (candidates() starts from it): the last step's
            self.cfg.update(cur)
        out = {"iterations": iters}
        for a in arms:
            dofs = self.arm_dofs[a]
            qa = q[:, dofs]
            last = min(hi[a], until)
            if last > lo[a]:
                qa[last:] = qa[last - 1]
            pe_a, re_a = pe_all[:, a].copy(), np.degrees(re_all[:, a])
            bad = ((pe_a > POSITION_TOL) | (re_a > ROTATION_TOL_DEG))
            bad[:lo[a]] = bad[hi[a]:] = False
            rng = ((qa - self.lower[dofs] < AT_LIMIT) | (self.upper[dofs] - qa < AT_LIMIT)).any(axis=1)
            out[a] = {"q": qa, "pe": pe_a, "re": re_a, "range": rng, "bad": int(bad.sum()),
                      "first_bad": _first_bad(bad), "until": until}
        return out

    def _settled_steps(self, t: int, stop: int, cur: np.ndarray, guess: np.ndarray, follows, lo, hi, targets,
                       out) -> tuple[int, np.ndarray]:
        """_track's steps t, t + 1, ... before `stop` that need no QP, taken at once: each starts from the joints
        of the step before with every active arm's replaced by its guess (finite, past its window's first step),
        and all its active arms are already converged there (_settled). Writes their joints and errors into
        out = (q, pe_all, re_all) as _track's loop would; returns (the first step it leaves to the loop, the
        joints after the last one it took)."""
        steps = np.arange(t, stop)
        active = follows & (lo <= steps[:, None]) & (steps[:, None] < hi)  # (m, 2)
        takes = active.any(axis=1)
        starts = np.empty((len(steps), len(cur)))
        for a, dofs in enumerate(self.arm_dofs):
            g = guess[steps][:, dofs]
            takes &= ~active[:, a] | (np.isfinite(g).all(axis=1) & (steps != lo[a]))
            # the arm's joints: its guess where active, else the last ones it had (cur before the first)
            last = np.maximum.accumulate(np.where(active[:, a], np.arange(len(steps)), -1))
            starts[:, dofs] = np.where((last >= 0)[:, None], g[np.maximum(last, 0)], cur[dofs])
        m = len(steps) if takes.all() else int(np.argmin(takes))
        if m == 0:
            return t, cur
        pos, R = targets
        settled, pe, re = self._settled(starts[:m], pos[t:t + m], R[t:t + m], active[:m])
        m = m if settled.all() else int(np.argmin(settled))
        if m == 0:
            return t, cur
        q, pe_all, re_all = out
        q[t:t + m], pe_all[t:t + m], re_all[t:t + m] = starts[:m], pe[:m], re[:m]
        return t + m, starts[m - 1].copy()

    def refine(self, q: np.ndarray, pos: np.ndarray, R: np.ndarray, wxyz: np.ndarray, active: np.ndarray,
               fps: float = 30.0, analytic: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joints (m, nq) moved onto targets (m, 2, ...) from the guesses q (m, nq), each arm only where
        active (m, 2); returns (q, position error (m, 2) m, rotation error (m, 2) degrees)."""
        out = np.array(q, float)
        pe_all, re_all = np.zeros(active.shape), np.zeros(active.shape)
        dt = 1.0 / fps
        if analytic and self.analytic is not None:
            for a, dofs in enumerate(self.arm_dofs):
                rows = np.flatnonzero(active[:, a])
                if not len(rows):
                    continue
                near = out[rows[:, None], dofs]
                exact = self.analytic(a, pos[rows, a], R[rows, a], near)
                # only the same branch, inside the ranges: elsewhere the interpolated joints are the better start
                use = ((exact >= self.lower[dofs]) & (exact <= self.upper[dofs])).all(axis=1) & \
                    (np.abs(exact - near).max(axis=1) < ANALYTIC_NEAR)
                out[rows[use][:, None], dofs] = exact[use]
        rows = np.flatnonzero(active.any(axis=1))
        # rows already on their targets (the closed form's exact joints) keep them: no QP, no per-row Python
        settled, pe, re = self._settled(out[rows], pos[rows], R[rows], active[rows])
        pe_all[rows[settled]], re_all[rows[settled]] = pe[settled], np.degrees(re[settled])
        for i in rows[~settled]:
            self.cfg.update(out[i])
            # without the closed form's start (near the wrist's singularity) the interpolated joints may be far off
            pe, re, _ = self._iterate(pos[i], R[i], wxyz[i], self.iterations if analytic else self.first_iterations, dt,
                                      active[i], give_up=analytic)
            out[i], pe_all[i], re_all[i] = self.cfg.q, pe, np.degrees(re)
        return out, pe_all, re_all
