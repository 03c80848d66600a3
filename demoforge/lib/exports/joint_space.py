"""Episodes in a robot's joint space, for the exports: each episode as the robot executes it (lib/sim:
for the ALOHA arms their ready-pose start, joint-space transits, the skill segments through inverse
kinematics and the time-scaling that keeps every joint within its servo's speed, sampled at the
episode's fps: lib/sim/robots/arm_motion.py), 14 values per step: six joints and the gripper's
normalized opening per arm, left first. An episode the arms slow down has more steps than it was
demonstrated with: the export writes what the arm runs.

An episode whose poses the arms cannot reach within the IK's tolerance (1 cm, 5 degrees at some step)
has no faithful joint trajectory: its joint values would put the gripper somewhere else than the
episode says. Such episodes are reported, never written as if they were right.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.exports import episode_starts
from demoforge.lib.sim import SimOptions, planned_execution


@dataclass
class JointEpisodes:
    """joints (F', D) and the executed pinch poses (F', 2, 8) of the episodes that the robot reaches,
    concatenated, with their lengths (N',) in executed steps; keep (N,) which of the given episodes those
    are; worst position (m) and rotation (degrees) residual and time-scale per given episode."""
    joints: np.ndarray
    poses: np.ndarray
    lengths: np.ndarray
    keep: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    time_scale: np.ndarray


def joint_episodes(robot, task: str, poses: np.ndarray, lengths: np.ndarray, keypoints: np.ndarray,
                   progress: Callable[[int], None] | None = None, fps: float = 30.0) -> JointEpisodes:
    """The joint trajectories of concatenated episodes poses (F, 2, 8) with lengths (N,) and each episode's
    object keypoints at its start (N, K, 3)."""
    starts = episode_starts(lengths)
    n = len(lengths)
    keep = np.zeros(n, bool)
    pe, re, scale = np.zeros(n), np.zeros(n), np.ones(n)
    joints, executed, kept_lengths = [], [], []
    options = SimOptions(robot=robot)
    for i in range(n):
        acts = np.asarray(poses[starts[i]:starts[i] + lengths[i]], np.float64)
        execution = planned_execution(task, keypoints[i], acts, fps, options)
        summary = execution.state.summary()
        pe[i], re[i] = summary["ik_position_error_m"], summary["ik_rotation_error_deg"]
        scale[i] = summary["time_scale"]
        keep[i] = summary["reachable"]
        if keep[i]:
            joints.append(robot.joint_values(execution))
            executed.append(execution.actions)
            kept_lengths.append(len(execution.actions))
        if progress is not None:
            progress(i + 1)
    width = len(robot.joint_names)
    return JointEpisodes(np.concatenate(joints) if joints else np.zeros((0, width)),
                         np.concatenate(executed) if executed else np.zeros((0, 2, 8)),
                         np.asarray(kept_lengths, np.int64), keep, pe, re, scale)
