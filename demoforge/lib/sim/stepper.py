"""The executor's episode loop one action frame at a time: what a step-by-step rollout (a Gymnasium
environment, demoforge.envs) runs, with the physics and the verdict of :func:`~demoforge.lib.sim.execute`.

    stepper = EpisodeStepper("pouring", SimOptions(robot=get_robot("aloha", "2f140")))
    stepper.reset(object_poses, pose0, joints0, max_frames=400)
    for pose, joints in frames:               # (2, 8) pinch pose + finger command g per arm; (12,) joints
        if stepper.step(pose, joints):        # True: a hard failure stopped the simulation
            break
    result = stepper.finish()                 # settle phase, predicate, failure class: a SimResult

What it shares with executor.py: the frame loop (loop.py: the finger command with the g mapping, the
release and the closing speed; the control steps of a frame, its records and the hard-failure stop; the
settle phase), the `wider_than_stroke` rule (`_stroke_events`) and the predicate with the failure
classification (`_finish`); the robot's own control (its binding's ``plan`` for the two frames
a step drives between: interpolated joint targets with the velocity feed-forward for the arms, mocap
targets for the grippers). Its loop is the executor's ``_run`` cut at the frames: the same pre-roll,
control steps, physics sub-steps, records, early stop at a hard failure, settle phase and early end at
rest; the targets of a step are interpolated between its two frames exactly as the executor interpolates
the whole episode (the quaternions kept hemisphere-continuous across steps; the grippers' orientation at
a frame before the last taken, as the executor takes it, from the next segment's start, so reset()'s
max_frames says which frame is the last). Driven with the frames ``execute`` plans for an episode (for the arms their joints and the close
commands of :func:`close_commands`), it gives the same physics, bit for bit, and the same SimResult
(tests/envs/test_robot_env.py).

What a rollout that cannot see ahead does differently (documented, and only these):

* the finger command is the given g itself. ``execute`` issues each close `close_lead_s` (0.3 s) before
  the demonstrated g switches to closed; :func:`close_commands` turns an episode's g into those commands;
* `wider_than_stroke` (a hand closing on an object wider than its opening) is judged, as ``execute``
  judges it, by where the hand is `close_lead_s` after the close command, so it is known that many
  frames later; the verdict dates it at the command (as ``execute``), and the simulation stops when it is
  known. Only when a physics hard failure stops the episode in between is the hand's latest pose used;
* nothing is planned: no `unreachable` / `joint_limit` (an arm's joints are commanded directly);
* positions are interpolated linearly between frames (SimOptions.position_interp "linear", the
  default; "cubic" needs the whole episode and is refused).
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

import numpy as np

from demoforge.lib.geometry import interpolate_poses, quat_normalize, xyzw_to_wxyz

from .executor import SimOptions, SimResult, _finish, _stroke_events, as_object_poses
from .loop import FingerCommand, Records, contact_scan, control_frame, frame_timing, preroll, record_frame, settle
from .robots.base import Execution
from .scene import SimScene


def close_commands(g: np.ndarray, lead: int) -> np.ndarray:
    """(n, 2) bool close commands from an episode's (n, 2) gripper states g (1 open, 0 closed), as execute
    issues them (executor._schedule): closed where g < 0.5, and each close `lead` frames early."""
    closed = np.asarray(g, float) < 0.5
    early = closed.copy()
    if lead > 0 and len(closed) > 1:
        for a in range(closed.shape[1]):
            for o in np.flatnonzero(closed[1:, a] & ~closed[:-1, a]) + 1:
                early[max(0, o - lead):o, a] = True
    return early


class _JointStep:
    """What an arm binding's plan reads of an arm motion (robots/aloha ArmMotion) for one step: the joints
    of the two frames it drives between; nothing planned, so no failure and no figures."""

    def __init__(self, q: np.ndarray):
        self.q = q

    def first_failure(self):
        return None

    def summary(self) -> dict:
        return {}


class EpisodeStepper:
    """One episode of one task with one robot, frame by frame (see the module docstring). Owns its
    compiled scene (not the per-process cache of get_scene: execute calls in between do not disturb it)."""

    def __init__(self, task_name: str, options: SimOptions | None = None, fps: float = 30.0):
        opt = options or SimOptions()
        if opt.position_interp != "linear":
            raise ValueError(f"a step-by-step rollout interpolates positions linearly between frames, not "
                             f"{opt.position_interp!r} (SimOptions.position_interp)")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps}")
        self.opt, self.fps = opt, float(fps)
        self.sc = sc = SimScene(task_name, opt.robot, opt.physics)
        self.spf, self.cpf, self.sub = frame_timing(fps, opt.physics.timestep, opt.ctrl_per_frame)
        self.tq = np.arange(1, self.cpf + 1) / self.cpf
        self.settle_frames = int(round(opt.settle_s * fps))
        self.lead = int(round(sc.spec.close_lead_s * fps))
        self.n = 0  # frames recorded so far (0: not reset)
        self.result: SimResult | None = None

    # ------------------------------------------------------------------ episode
    def reset(self, object_poses, pose0: np.ndarray, joints0: np.ndarray | None = None, max_frames: int = 900) -> None:
        """Objects at object_poses ((n_obj, 4, 4) or the task's (K, 3) keypoints), the robot at its first frame:
        pinch poses with finger commands pose0 (2, 8) and, for an arm robot, its joints joints0; then the
        pre-roll. At most max_frames frames (this one included) follow before finish()."""
        sc, opt = self.sc, self.opt
        obj0 = as_object_poses(sc.task, object_poses)
        if not np.isfinite(obj0).all():
            raise ValueError("object poses contain non-finite values")
        if bool(sc.robot.joint_names) != (joints0 is not None):
            raise ValueError(f"the {sc.robot.name} robot {'needs' if sc.robot.joint_names else 'has no'} joints")
        if int(max_frames) < 1:
            raise ValueError(f"max_frames must be at least 1, got {max_frames}")
        self.t_wall = time.perf_counter()
        self.obj0, self.max_frames = obj0, int(max_frames)
        self.pos = np.zeros((self.max_frames, 2, 3))
        self.closed = np.zeros((self.max_frames, 2), bool)
        self.joints = None if joints0 is None else np.asarray(joints0, float).copy()
        pose0 = np.asarray(pose0, float)
        quat0 = pose0[:, 3:7] / np.linalg.norm(pose0[:, 3:7], axis=-1, keepdims=True)
        self.quat, self.aligned = quat0, quat0  # the last frame's unit quaternion, and it hemisphere-aligned
        self.pose = pose0.copy()
        closed0 = pose0[:, 7] < 0.5
        self.fc = FingerCommand(sc.spec, closed0, 1.0 / (self.fps * self.cpf))
        plan0 = sc.binding.plan(sc, self._execution(pose0[None], self.joints, None), quat0[None], np.zeros((0, 2, 3)),
                                np.zeros((0, 2, 4)), self.cpf, self.fps)
        sc.reset(obj0, np.concatenate([pose0[:, :3], quat0], axis=-1), np.where(closed0, 0.0, sc.spec.opening), plan0)
        sc.model.opt.timestep = 1.0 / (self.fps * self.spf)
        self.steps = self.pre = preroll(sc, opt.preroll_s)
        self.rec = Records(sc, self.max_frames + self.settle_frames, opt, None)
        self.contacts = contact_scan(sc, self.rec)
        self.plan_events: list = []
        self.pending: list[int] = []  # frames of close commands whose wider_than_stroke check is not known yet
        self.stop: int | None = None
        self.result = None
        self.n = 0
        self._add_frame(pose0)
        record_frame(sc, self.rec, 0)

    @staticmethod
    def _execution(poses: np.ndarray, joints_prev: np.ndarray | None, joints: np.ndarray | None) -> Execution:
        if joints_prev is None:
            return Execution(poses)
        q = joints_prev[None] if joints is None else np.stack([joints_prev, joints])
        return Execution(poses, _JointStep(q))

    def _add_frame(self, pose: np.ndarray) -> None:
        i = self.n
        self.pos[i] = pose[:, :3]
        self.closed[i] = pose[:, 7] < 0.5
        if self.closed[i].any() and (i == 0 or (self.closed[i] & ~self.closed[i - 1]).any()):
            self.pending.append(i)
        self.n = i + 1

    def step(self, pose: np.ndarray, joints: np.ndarray | None = None) -> bool:
        """Drive the robot to the next frame: pinch poses with finger commands pose (2, 8) (an arm robot: the
        forward kinematics of its joint targets joints (12,), with the commands); physics over the frame.
        True when a hard failure stopped the simulation (finish() gives the verdict)."""
        if self.n == 0 or self.stop is not None or self.result is not None or self.n >= self.max_frames:
            raise RuntimeError("the episode has ended (or was never reset): call reset()")
        sc = self.sc
        if (self.joints is None) != (joints is None):
            raise ValueError(f"the {sc.robot.name} robot {'has no' if self.joints is None else 'needs'} joints")
        i = self.n
        pose = np.asarray(pose, float)
        quat = pose[:, 3:7] / np.linalg.norm(pose[:, 3:7], axis=-1, keepdims=True)
        # the executor interpolates the whole episode's hemisphere-continuous quaternions: the same two here
        tp, tq = interpolate_poses(np.arange(2.0), np.stack([self.pos[i - 1], pose[:, :3]]),
                                   np.stack([self.aligned, quat]), self.tq, rotation="slerp", position="linear")
        flip = np.sum(quat_normalize(quat) * quat_normalize(self.aligned), axis=-1) < 0.0
        self.aligned = np.where(flip[:, None], -quat, quat)
        if i < self.max_frames - 1:  # the executor reaches a frame before the last as the next segment's start
            tq[-1] = interpolate_poses(np.arange(2.0), np.stack([pose[:, :3]] * 2), np.stack([self.aligned] * 2), [0.0],
                                       rotation="slerp", position="linear")[1][0]
        plan = sc.binding.plan(sc, self._execution(np.stack([self.pose, pose]), self.joints,
                                                   None if joints is None else np.asarray(joints, float)),
                               np.stack([self.quat, quat]), tp, xyzw_to_wxyz(tq), self.cpf, self.fps)
        self.quat, self.pose = quat, pose.copy()
        if joints is not None:
            self.joints = np.asarray(joints, float).copy()
        self._add_frame(pose)
        control_frame(sc, i, self.sub, tuple(self.closed[i].tolist()), tp, self.fc, self.contacts, plan.apply)
        self.steps += self.spf
        record_frame(sc, self.rec, i)
        if self.opt.stop_on_hard_failure and self.rec.hard_failure(i):
            self._stop(i)
        if self.pending and self.pending[0] + self.lead <= i:
            self._stroke_check(final=False)
        return self.stop is not None

    def _stop(self, i: int) -> None:
        self.stop = i if self.stop is None else min(self.stop, i)
        if self.pending:  # stopped before the hand reached where it closes: judged where it is now
            self._stroke_check(final=True)

    def _stroke_check(self, final: bool) -> None:
        """The executor's wider_than_stroke rule on the frames so far, for the close commands whose hand
        position `lead` frames later is known (all of them when final)."""
        n = self.n
        sch: Any = SimpleNamespace(closed_cmd=self.closed[:n], pos=self.pos[:n])  # what _stroke_events reads of a _Schedule
        known = [o for o in self.pending if final or o + self.lead <= n - 1]
        self.pending = [o for o in self.pending if o not in known]
        events = [e for e in _stroke_events(self.sc, self.obj0, sch, self.fps) if e.frame in known]
        if events and self.opt.stop_on_hard_failure:
            self.stop = min(e.frame for e in events) if self.stop is None else min(self.stop, *(e.frame for e in events))
        self.plan_events = sorted(self.plan_events + events, key=lambda e: e.frame)

    def predicate(self) -> tuple[bool, str]:
        """The task's success predicate on the state now and the frames so far (not a verdict: finish() is)."""
        ok, detail = self.sc.task.success(self.sc.model, self.sc.data, self.rec.hist[:self.n])
        return bool(ok), str(detail)

    def finish(self) -> SimResult:
        """The settle phase after the last frame (holding its commands; ending early at rest), the predicate
        and the failure classification, as execute ends an episode; idempotent."""
        if self.result is not None:
            return self.result
        if self.n == 0:
            raise RuntimeError("the episode was never reset: call reset()")
        if self.pending:
            self._stroke_check(final=True)
        settled = self._settle() if self.stop is None else None
        steps = self.steps if self.stop is None or self.stop >= self.n - 1 else self.pre + self.stop * self.spf
        sch = SimpleNamespace(closed_cmd=self.closed[:self.n], settle_frames=self.settle_frames)
        self.result = _finish(self.sc, self.opt, self.fps, self.n, sch, SimpleNamespace(summary={}), self.plan_events,
                              self.rec, self.stop, settled, steps, self.t_wall)
        return self.result

    def _settle(self) -> int | None:
        """executor._run's settle phase (loop.settle): (the frame it ended at rest, or None); sets self.stop on
        a hard failure."""
        n, rec = self.n, self.rec
        T = n + self.settle_frames
        rec.T = T
        rec.truncate(T - 1)
        stop, settled, last = settle(self.sc, rec, self.opt, self.sub, tuple(self.closed[n - 1].tolist()),
                                     self.pos[n - 1], self.fc, self.contacts, n, T)
        self.steps += (last - n + 1) * self.spf
        if stop is not None:
            self.stop = stop
        return settled


__all__ = ["EpisodeStepper", "close_commands"]
