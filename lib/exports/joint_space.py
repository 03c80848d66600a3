"""Episodes in a robot's joint space, for the exports: every step's (2, 8) gripper poses through the robot's
inverse kinematics (lib/sim/robots; for the ALOHA arms 14 values per step: six joints and the gripper's
normalized opening per arm, left first).

An episode whose poses the arms cannot reach within the IK's tolerance (1 cm, 5 degrees at some step)
has no faithful joint trajectory: its joint values would put the gripper somewhere else than the
episode says. Such episodes are reported, never written as if they were right.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.exports import episode_starts


@dataclass
class JointEpisodes:
    """joints (F, D) of the episodes that the robot reaches, concatenated; keep (N,) which of the
    given episodes those are; worst position (m) and rotation (degrees) residual per given episode."""
    joints: np.ndarray
    keep: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray


def joint_episodes(robot, task: str, poses: np.ndarray, lengths: np.ndarray,
                   progress: Callable[[int], None] | None = None) -> JointEpisodes:
    """The joint trajectories of concatenated episodes poses (F, 2, 8) with lengths (N,)."""
    starts = episode_starts(lengths)
    n = len(lengths)
    keep = np.zeros(n, bool)
    pe, re = np.zeros(n), np.zeros(n)
    parts = []
    for i in range(n):
        acts = np.asarray(poses[starts[i]:starts[i] + lengths[i]], np.float64)
        joints, sol = robot.joint_trajectory(task, acts)
        summary = sol.summary()
        pe[i], re[i] = summary["ik_position_error_m"], summary["ik_rotation_error_deg"]
        keep[i] = summary["reachable"]
        if keep[i]:
            parts.append(joints)
        if progress is not None:
            progress(i + 1)
    width = len(robot.joint_names)
    return JointEpisodes(np.concatenate(parts) if parts else np.zeros((0, width)), keep, pe, re)
