"""An episode made the ViperX arms' own: the poses each arm follows in its window, from the demonstration.

    follow, grasps = ArmsRetargeting(solver, bases, ready, speed, task, spec)(actions, windows, keypoints0)

1. The objects' motion as demonstrated (lib/sim/robots/retarget.py): each object at its place at the
   start (fitted to the episode's keypoints), carried rigidly by the hand that closes on it.
2. Each window's grasp (grasp_choice.py): the turn about the held object's symmetry axis and the
   gripper's half-turn that the arm follows best over the whole window. A window in which the arm
   holds more than one object, or none, only gets the half-turn.
3. The fingers kept `TABLE_CLEARANCE` above the table top: a pinch pose whose fingertips would go lower
   is raised (eased in and out), since an arm's position servo pushes through the table where a
   person's hand gives way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demoforge.lib.geometry import pose7_to_transform, transform_to_pose8, umeyama
from demoforge.lib.sim.gripper import GripperSpec
from demoforge.lib.sim.robots.retarget import finger_half_width, lift_above_table, lowest_finger_z, object_trajectories
from demoforge.lib.trajectories.segmentation import held_objects

from .closed_form import ViperXBatchIK
from .grasp_choice import GraspChoice, choose_grasps
from .model import BasePose

TABLE_CLEARANCE = 0.0  # m between the lowest fingertip and the table top
NO_GUESS_WRIST = 0.15  # |sin(wrist angle)| below which the closed form gives no guess
# per hand: the narrowest object whose grasp may turn while held. A pad's friction turns a held object about its
# axis with a torque in proportion to its radius; in ALOHA's fingers the whisk's 12 mm handle rolls instead
# (scripted mix_bowl: 2/8 turning, 5/8 not), in the 2F-140's pads it turns (database episodes: 17/20 and 14/20)
TURN_HELD_MIN_WIDTH = {"aloha_vx300s": 0.03}
GRASP_REACH = 0.12  # m from the pinch point to the nearest keypoint of an object it closes on (objects up to 20 cm)


@dataclass(frozen=True)
class Grasps:
    """What the retargeting chose for an episode: each arm's grasp, the most it raised a pose (m), and the
    closed-form joints (T, 12) of the poses the arms follow, on the branch the choice tracked (the IK's
    starting point at each step; the ready pose outside the windows; NaN where the wrist is nearly straight:
    its two rolls are one there, and the closed form's split of them jumps from step to step)."""
    arms: tuple[GraspChoice, GraspChoice]
    lift: tuple[float, float]
    joints: np.ndarray


def object_poses_at_start(task, keypoints0: np.ndarray) -> np.ndarray:
    """(n_obj, 4, 4) each object's pose fitted to its keypoints (K, 3) (rigid, no scale)."""
    kp = np.asarray(keypoints0, float)
    owner = task.keypoint_object
    out = np.tile(np.eye(4), (len(task.objects), 1, 1))
    for k in range(len(task.objects)):
        _, R, t = umeyama(task.keypoints_local[owner == k], kp[owner == k], with_scale=False)
        out[k, :3, :3], out[k, :3, 3] = R, t
    return out


def window_objects(held: np.ndarray, windows: np.ndarray, hand: np.ndarray, keypoints0: np.ndarray,
                   keypoint_object: np.ndarray) -> np.ndarray:
    """(2,) the one object each arm holds in its window (-1: none, more than one, or the hand closes farther
    than GRASP_REACH from the object's keypoints: turning such a 'grasp' about the object would only swing
    the hand around it)."""
    out = np.full(2, -1)
    for a in range(2):
        inside = held[windows[a, 0]:windows[a, 1], a]
        objs = np.unique(inside[inside >= 0])
        if len(objs) != 1:
            continue
        o = int(objs[0])
        close = windows[a, 0] + int(np.argmax(inside >= 0))
        if np.linalg.norm(keypoints0[keypoint_object == o] - hand[close, a, :3, 3], axis=1).min() <= GRASP_REACH:
            out[a] = o
    return out


class ArmsRetargeting:
    """The retargeting of one task's episodes for two ViperX arms at their bases (see the module docstring)."""

    def __init__(self, solver: ViperXBatchIK, bases: tuple[BasePose, BasePose], ready: np.ndarray, speed: np.ndarray,
                 task, spec: GripperSpec, clearance: float = TABLE_CLEARANCE):
        self.solver, self.bases, self.task, self.spec = solver, bases, task, spec
        self.ready, self.speed = np.asarray(ready, float), np.asarray(speed, float)
        self.clearance = clearance

    def __call__(self, actions: np.ndarray, windows: np.ndarray, keypoints0: np.ndarray) -> tuple[np.ndarray, Grasps]:
        actions = np.asarray(actions, float)
        task = self.task
        hand = pose7_to_transform(actions[..., :7])
        g = actions[..., 7]
        held = held_objects(actions, np.asarray(keypoints0, float), task.keypoint_object)
        objs = object_trajectories(hand, g < 0.5, held, object_poses_at_start(task, keypoints0))
        window_held = window_objects(held, windows, hand, np.asarray(keypoints0, float), task.keypoint_object)
        widths = np.append(task.grasp_widths, 0.0)  # index -1: nothing held
        half = finger_half_width(g, widths[held], self.spec.opening)  # (T, 2)

        def lowest(arm: int, steps: np.ndarray, poses: np.ndarray) -> np.ndarray:
            flat = poses.reshape(-1, 4, 4)
            z = lowest_finger_z(flat, np.tile(half[steps, arm], len(poses)), self.spec)
            return z.reshape(poses.shape[:2]) - self.clearance

        choice = choose_grasps(self.solver, self.bases, self.ready, self.speed, hand, g < 0.5, objs, window_held,
                               np.array([o.symmetry for o in task.objects]), windows, lowest, task.grasp_widths,
                               TURN_HELD_MIN_WIDTH.get(self.spec.name, 0.0))
        out = choice.hand
        lifts = [0.0, 0.0]
        for a in range(2):
            w0, w1 = (int(v) for v in windows[a])
            if w1 <= w0:
                continue
            out[w0:w1, a], lift = lift_above_table(out[w0:w1, a], half[w0:w1, a], self.spec, self.clearance)
            lifts[a] = float(lift.max())
        joints = self._joints(out, windows, choice.tracks)
        return transform_to_pose8(out, g), Grasps(choice.arms, (lifts[0], lifts[1]), joints)

    def _joints(self, hand: np.ndarray, windows: np.ndarray, tracks) -> np.ndarray:
        """(T, 12) each arm's closed-form joints in its window: at every step the branch nearest the choice's
        track (interpolated between its samples)."""
        out = np.tile(self.ready, (len(hand), 1))
        for a in range(2):
            if tracks[a] is None:
                continue
            w0, w1 = (int(v) for v in windows[a])
            steps, q_track = tracks[a]
            near = np.stack([np.interp(np.arange(w0, w1), steps, q_track[:, j]) for j in range(6)], axis=1)
            sol = self.solver.solve(self.bases[a], hand[w0:w1, a, :3, 3], hand[w0:w1, a, :3, :3])
            b = np.abs(sol.q - near[:, None]).max(axis=-1).argmin(axis=1)
            q = sol.q[np.arange(w1 - w0), b]
            q[np.abs(np.sin(q[:, 4])) < NO_GUESS_WRIST] = np.nan  # the rolls are ill-defined there: no guess
            out[w0:w1, 6 * a:6 * a + 6] = q
        return out


__all__ = ["ArmsRetargeting", "Grasps", "TABLE_CLEARANCE", "object_poses_at_start", "window_objects"]
