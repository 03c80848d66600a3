"""The closed-loop policy's training data: episodes of a database as an arm robot executes them, frame by
frame, in the features of the joint-space LeRobot export (lib/exports/joint_space.py) and of the Gymnasium
environment (demoforge.envs): ``observation.state`` (14 joint values), ``observation.environment_state``
(the 11 object keypoints carried by the closed hands) and the action, the next frame's state.

One difference from the export's rows, on purpose: the gripper columns are the close *commands* the robot
check issues (each close 0.3 s before the demonstrated hand closes: lib/sim/stepper.close_commands), not
the demonstrated opening. A policy imitating the demonstrated opening closes 0.3 s late in the environment,
where the command is the action (see DemoforgeEnv.replay_actions)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from demoforge.lib.exports import episode_starts
from demoforge.lib.exports.joint_space import joint_episodes
from demoforge.lib.exports.object_state import episode_object_keypoints
from demoforge.lib.sim.stepper import close_commands

GRIPPER_COLUMNS = (6, 13)  # the two arms' gripper values in a 14-value joint state


@dataclass
class JointDemos:
    """states (F, 14) and environment states (F, 3K) of the kept episodes, concatenated; lengths (N',) in
    frames; keep (N,) which of the given episodes the arms reach (the others have no joint trajectory);
    robot (its label, `aloha+2f140`) and task: whose joint space and kinematic model."""
    states: np.ndarray
    environment: np.ndarray
    lengths: np.ndarray
    keep: np.ndarray
    robot: str
    task: str

    def __len__(self) -> int:
        return len(self.lengths)

    def starts(self) -> np.ndarray:
        return episode_starts(self.lengths)

    def episode(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        s = int(self.starts()[i])
        return self.states[s:s + self.lengths[i]], self.environment[s:s + self.lengths[i]]

    def held(self, frames: int) -> "JointDemos":
        """Each episode followed by `frames` frames of its last one: the arms at rest after the task, so that a
        policy learns to stay there (an environment runs on until its step limit or the task's success)."""
        if frames <= 0:
            return self
        starts = self.starts()
        rows = np.concatenate([np.r_[np.arange(s, s + m), np.full(frames, s + m - 1)]
                               for s, m in zip(starts, self.lengths)]) if len(self) else np.zeros(0, np.int64)
        return JointDemos(self.states[rows], self.environment[rows], self.lengths + frames, self.keep, self.robot,
                          self.task)

    def save(self, path) -> None:
        np.savez_compressed(path, states=self.states, environment=self.environment, lengths=self.lengths,
                            keep=self.keep, robot=self.robot, task=self.task)

    @classmethod
    def load(cls, path) -> "JointDemos":
        with np.load(path) as z:
            return cls(z["states"], z["environment"], z["lengths"], z["keep"], str(z["robot"]), str(z["task"]))


def commanded_grippers(states: np.ndarray, lengths: np.ndarray, lead: int) -> np.ndarray:
    """The states (F, 14) with each episode's gripper columns turned into the close commands (1 open, 0 close)."""
    out = np.array(states, np.float64)
    cols = list(GRIPPER_COLUMNS)
    for s, m in zip(episode_starts(lengths), lengths):
        out[s:s + m, cols] = np.where(close_commands(out[s:s + m, cols], lead), 0.0, 1.0)
    return out


def joint_demos(robot, task, poses: np.ndarray, lengths: np.ndarray, keypoints: np.ndarray,
                progress: Callable[[int], None] | None = None, fps: float = 30.0) -> JointDemos:
    """The episodes poses (F, 2, 8) with lengths (N,) and start keypoints (N, K, 3) as `robot` (an arm robot)
    executes them, each close commanded the robot's close lead early (as EpisodeStepper.lead)."""
    js = joint_episodes(robot, task.name, poses, lengths, keypoints, progress=progress, fps=fps)
    states = commanded_grippers(js.joints, js.lengths, int(round(robot.gripper.close_lead_s * fps)))
    pinch = np.array(js.poses, np.float64)
    pinch[:, :, 7] = states[:, list(GRIPPER_COLUMNS)]  # the keypoints follow the commanded hands, as the env's do
    env = episode_object_keypoints(pinch, js.lengths, np.asarray(keypoints)[js.keep], task.keypoint_object)
    return JointDemos(states.astype(np.float32), env.reshape(len(env), -1).astype(np.float32),
                      np.asarray(js.lengths, np.int64), js.keep, robot.label, task.name)


__all__ = ["GRIPPER_COLUMNS", "JointDemos", "commanded_grippers", "joint_demos"]
