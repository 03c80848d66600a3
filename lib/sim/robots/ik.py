"""Inverse kinematics of two arms along an episode, with mink (differential IK on MuJoCo, a QP per step).

    ik = ArmsIK(xml, assets, sites=("left_hand_pinch", "right_hand_pinch"), arm_joints=(range(6), range(6, 12)),
                speed=speed_limits, seeds=seed_fn)
    sol = ik.solve(actions)          # (n, 2, 8) gripper poses -> sol.q (n, 12), residuals per step
    sol.first_failure(0.01, 5.0)     # (step, arm, "unreachable" | "joint_limit", detail) or None

One MuJoCo model holds both arms (only their joints: the hands' fingers do not move the pinch sites),
and each QP solves both arms' pose tasks together (one 12-dof problem per iteration, not two 6-dof
ones: the QP costs about the same, the Python around it half). Along the episode the solution is warm-
started: each step starts from the previous step's joints, so at 30 fps one iteration usually lands
within 0.5 mm and 0.25 degrees of the target, and at most `iterations` are spent per step. Each
iteration is mink's QP (mink.build_ik: the tasks' weighted residuals and the configuration limits)
solved by DAQP through qpsolvers; mink.solve_ik would add a limits check of the configuration that
the clip below makes redundant, a third of an iteration's time. Limits:
mink's ConfigurationLimit keeps every joint inside its range; each step's change is clipped to the
joint's speed limit times the step's duration (the arm cannot move faster than its servos), and the
residual is measured after the clip. The first step is solved from the robot's seeds (a few rest
configurations) without a speed limit: the robot moves there before the episode starts.

A warm-started solution stays on the branch it starts on: a wrist that starts rolled one way reaches
the end of its range where the same poses, started on the other wrist branch (for a roll-pitch-roll
wrist: roll + pi, -pitch, roll + pi, the same pinch pose), would not. When an arm fails a step, the
episode is tracked again from the first step's other branch (`flip`), and each arm keeps the run in
which it fails fewer steps (the two arms' problems are independent: separate tasks and joints).

A step fails when a pinch point ends more than `tol_position` metres or `tol_rotation_deg` degrees from
its target; the failure is `unreachable` when the target lies beyond the arm's reach (the robot's
`out_of_reach`: farther from the shoulder than the stretched arm) or no joint is at a limit, and
`joint_limit` when a joint of that arm is at its range's end or was clipped to its speed limit at that
step (the pose lies within reach, but the joint cannot follow).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

POSITION_TOL = 0.01  # m
ROTATION_TOL_DEG = 5.0
CONVERGED_POSITION = 5e-4  # m: stop iterating a step below this ...
CONVERGED_ROTATION = np.radians(0.25)  # ... and this (half the accuracy the tests ask of a reachable pose)
AT_LIMIT = 0.02  # rad from a range's end counts as at the limit (mink approaches it geometrically)


@dataclass
class IKSolution:
    """q (n, nq) joint angles per step; position_error (n, 2) m and rotation_error (n, 2) degrees of each
    arm's pinch pose after IK; at_range_limit, at_speed_limit (n, 2): a joint of the arm at the end of its
    range, or moved at its speed limit into the step; iterations: QP solves in all."""
    q: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    at_range_limit: np.ndarray
    at_speed_limit: np.ndarray
    iterations: int
    out_of_reach: np.ndarray | None = None  # (n, 2) the target lies beyond the stretched arm

    def failed_steps(self, tol_position: float = POSITION_TOL, tol_rotation_deg: float = ROTATION_TOL_DEG) -> np.ndarray:
        """(n, 2) bool: the arm's pose is off its target by more than the tolerances."""
        return (self.position_error > tol_position) | (self.rotation_error > tol_rotation_deg)

    def first_failure(self, tol_position: float = POSITION_TOL,
                      tol_rotation_deg: float = ROTATION_TOL_DEG) -> tuple[int, int, str, str] | None:
        """(step, arm, failure, detail) of the first step off its target, or None."""
        bad = self.failed_steps(tol_position, tol_rotation_deg)
        if not bad.any():
            return None
        t = int(np.argmax(bad.any(axis=1)))
        arm = int(np.argmax(bad[t]))
        far = self.out_of_reach is not None and bool(self.out_of_reach[t, arm])
        limited = not far and (self.at_range_limit[t, arm] or self.at_speed_limit[t, arm])
        why = ("the target beyond the arm's reach" if far else
               "a joint at the end of its range" if self.at_range_limit[t, arm] else
               "a joint at its speed limit" if self.at_speed_limit[t, arm] else "no joint at a limit")
        detail = (f"arm {arm} ends {self.position_error[t, arm] * 1000:.0f} mm and {self.rotation_error[t, arm]:.1f} deg "
                  f"from its pose at step {t} ({why}; tolerance {tol_position * 1000:.0f} mm, {tol_rotation_deg:g} deg)")
        return t, arm, "joint_limit" if limited else "unreachable", detail

    def summary(self) -> dict:
        """Per-episode figures: the worst residuals (m, degrees) and whether every step is within tolerance."""
        return {"ik_position_error_m": float(self.position_error.max()) if self.position_error.size else 0.0,
                "ik_rotation_error_deg": float(self.rotation_error.max()) if self.rotation_error.size else 0.0,
                "reachable": not bool(self.failed_steps().any())}


def _first_bad(sol: IKSolution) -> int:
    """The first step off its target (len when none)."""
    bad = sol.failed_steps().any(axis=1)
    return int(np.argmax(bad)) if bad.any() else len(bad)


def _rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) between rotation matrices (..., 3, 3)."""
    c = (np.einsum("...ij,...ij->...", Ra, Rb) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


class ArmsIK:
    """Warm-started differential IK of two arms with mink (see the module docstring)."""

    def __init__(self, xml: str, assets: dict, sites: Sequence[str], arm_joints: Sequence[Sequence[int]],
                 speed: Sequence[float], seeds: Callable[[np.ndarray], list[np.ndarray]],
                 flip: Callable[[np.ndarray], np.ndarray] | None = None,
                 out_of_reach: Callable[[np.ndarray], np.ndarray] | None = None, iterations: int = 3, first_iterations: int = 60, position_cost: float = 1.0,
                 orientation_cost: float = 0.15, lm_damping: float = 1e-4):
        import mink
        import mujoco
        import qpsolvers

        self.mink, self.qpsolvers = mink, qpsolvers
        self.model = mujoco.MjModel.from_xml_string(xml, assets)
        self.cfg = mink.Configuration(self.model)
        self.sites = np.array([self.model.site(s).id for s in sites])
        self.tasks = [mink.FrameTask(s, "site", position_cost=position_cost, orientation_cost=orientation_cost,
                                     lm_damping=lm_damping) for s in sites]
        self.limits = [mink.ConfigurationLimit(self.model)]
        self.arm_dofs = [np.asarray(list(j), int) for j in arm_joints]
        self.speed = np.asarray(speed, float)
        self.lower, self.upper = self.model.jnt_range[:, 0].copy(), self.model.jnt_range[:, 1].copy()
        self.seeds, self.flip, self.out_of_reach = seeds, flip, out_of_reach
        self.iterations, self.first_iterations = int(iterations), int(first_iterations)

    def _set_targets(self, pos: np.ndarray, wxyz: np.ndarray) -> None:
        SE3 = self.mink.SE3
        for a in range(2):
            self.tasks[a].set_target(SE3(wxyz_xyz=np.concatenate([wxyz[a], pos[a]])))

    def _errors(self, pos: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.cfg.data
        diff = d.site_xpos[self.sites] - pos
        pe = np.sqrt(np.einsum("ai,ai->a", diff, diff))
        re = _rotation_angle(d.site_xmat[self.sites].reshape(2, 3, 3), R)
        return pe, re

    def _iterate(self, pos, R, wxyz, max_iter: int, dt: float, give_up: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """Up to max_iter QP steps towards the targets from the current configuration; stops early once
        both arms are converged or (give_up) an iteration no longer brings the unconverged ones closer
        (an arm held by a limit or out of reach stays where it is: more iterations would only cost time)."""
        pe, re = self._errors(pos, R)
        k = 0
        off = np.maximum(pe / CONVERGED_POSITION, re / CONVERGED_ROTATION)
        if (off > 1.0).any():
            self._set_targets(pos, wxyz)  # only when a QP is solved (the prediction often lands already)
        while k < max_iter and (off > 1.0).any():
            result = self.qpsolvers.solve_problem(self.mink.build_ik(self.cfg, self.tasks, dt, 1e-12, self.limits),
                                                  solver="daqp")
            if not result.found:  # no step within the limits: the configuration stays
                break
            self.cfg.integrate_inplace(result.x / dt, dt)
            pe, re = self._errors(pos, R)
            k += 1
            before, off = off, np.maximum(pe / CONVERGED_POSITION, re / CONVERGED_ROTATION)
            if give_up and not (off[before > 1.0] < 0.8 * before[before > 1.0]).any():
                break
        return pe, re, k

    def solve(self, poses: np.ndarray, fps: float = 30.0, until_failure: bool = False) -> IKSolution:
        """Joints for every step of (n, 2, >= 7) poses [x y z qx qy qz qw ...] (world frame).

        until_failure: stop tracking at the first step off its target (the simulator, which stops there
        anyway, needs no more): the later steps hold that step's joints and residuals, and of the two wrist
        branches the one that gets further is kept."""
        from scipy.spatial.transform import Rotation

        poses = np.asarray(poses, float)
        n = len(poses)
        pos = poses[..., :3]
        xyzw = poses[..., 3:7] / np.linalg.norm(poses[..., 3:7], axis=-1, keepdims=True)
        R = Rotation.from_quat(xyzw.reshape(-1, 4)).as_matrix().reshape(n, 2, 3, 3)
        wxyz = xyzw[..., [3, 0, 1, 2]]
        q0, pe0, re0, iters = self._first_step(poses[0], pos[0], R[0], wxyz[0])
        sol = self._track(q0, pe0, re0, pos, R, wxyz, fps, until_failure)
        sol.iterations += iters
        bad = sol.failed_steps().sum(axis=0)
        if self.flip is not None and bad.any():
            q1 = self.flip(q0)
            self.cfg.update(q1)
            pe1, re1 = self._errors(pos[0], R[0])
            other = self._track(q1, pe1, re1, pos, R, wxyz, fps, until_failure)
            sol.iterations += other.iterations
            if until_failure:  # a run stopped at its first failure: keep the run that got further
                if _first_bad(other) > _first_bad(sol):
                    other.iterations = sol.iterations
                    sol = other
                better = np.zeros(2, bool)
            else:
                better = other.failed_steps().sum(axis=0) < bad
            for a, dofs in enumerate(self.arm_dofs):
                if better[a]:
                    sol.q[:, dofs] = other.q[:, dofs]
                    for k in ("position_error", "rotation_error", "at_range_limit", "at_speed_limit"):
                        getattr(sol, k)[:, a] = getattr(other, k)[:, a]
        if self.out_of_reach is not None:
            sol.out_of_reach = np.asarray(self.out_of_reach(poses), bool)
        return sol

    def _first_step(self, pose0, pos, R, wxyz):
        """The first step from each seed; each arm keeps its best (the two arms' problems are
        independent). Stops at the first seed that puts both arms within tolerance. Returns q, the
        errors and the iterations spent."""
        iters = 0
        best_q = best_pe = best_re = best_score = None
        for seed in self.seeds(pose0):
            self.cfg.update(np.clip(np.asarray(seed, float), self.lower, self.upper))
            pe, re, k = self._iterate(pos, R, wxyz, self.first_iterations, 1.0, give_up=False)
            iters += k
            score = np.maximum(pe / POSITION_TOL, np.degrees(re) / ROTATION_TOL_DEG)
            if best_q is None:
                best_q, best_pe, best_re, best_score = self.cfg.q.copy(), pe, re, score
            else:
                for a, dofs in enumerate(self.arm_dofs):
                    if score[a] < best_score[a]:
                        best_q[dofs] = self.cfg.q[dofs]
                        best_pe[a], best_re[a], best_score[a] = pe[a], re[a], score[a]
            if (best_score < 0.05).all():
                break
        self.cfg.update(best_q)
        return best_q, best_pe, best_re, iters

    def _track(self, q0, pe0, re0, pos, R, wxyz, fps, until_failure: bool = False) -> IKSolution:
        """Warm-started IK from q0 along the steps, each step's change clipped to the speed limits (with
        until_failure: up to the first step off its target, the later steps holding it)."""
        n = len(pos)
        q = np.zeros((n, self.model.nq))
        pe_all, re_all = np.zeros((n, 2)), np.zeros((n, 2))
        range_lim, speed_lim = np.zeros((n, 2), bool), np.zeros((n, 2), bool)
        clipped_all = np.zeros((n, self.model.nq), bool)
        q[0], pe_all[0], re_all[0] = q0, pe0, re0
        self.cfg.update(q0)
        iters = 0
        dt = 1.0 / fps
        step_max = self.speed * dt
        for t in range(1, n):
            if t > 1:  # predict: the joints keep their last step's velocity (within range)
                self.cfg.update(np.clip(2 * q[t - 1] - q[t - 2], self.lower, self.upper))
            pe, re, k = self._iterate(pos[t], R[t], wxyz[t], self.iterations, dt)
            iters += k
            dq = self.cfg.q - q[t - 1]
            clipped = np.abs(dq) > step_max
            if clipped.any():  # the servos cannot move that far in one step: the arm lags behind
                self.cfg.update(q[t - 1] + np.clip(dq, -step_max, step_max))
                pe, re = self._errors(pos[t], R[t])
            q[t], pe_all[t], re_all[t], clipped_all[t] = self.cfg.q, pe, re, clipped
            if until_failure and ((pe > POSITION_TOL) | (np.degrees(re) > ROTATION_TOL_DEG)).any():
                q[t + 1:], pe_all[t + 1:], re_all[t + 1:], clipped_all[t + 1:] = q[t], pe, re, clipped
                break
        for a, dofs in enumerate(self.arm_dofs):
            speed_lim[:, a] = clipped_all[:, dofs].any(axis=1)
            qa = q[:, dofs]
            range_lim[:, a] = ((qa - self.lower[dofs] < AT_LIMIT) | (self.upper[dofs] - qa < AT_LIMIT)).any(axis=1)
        return IKSolution(q, pe_all, np.degrees(re_all), range_lim, speed_lim, iters)
