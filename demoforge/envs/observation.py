"""The environment's observations as the exports define them, built online, one frame at a time.

Feature names, shapes and dtypes come from the LeRobot export itself
(demoforge.lib.exports.lerobot.features): ``observation.state`` (the robot's 14 joint values, or the
grippers' 16 pose values), ``observation.environment_state`` (the 11 object keypoints, 33 float32) and
``observation.images.<camera>`` (RGB uint8, the export's video frames).

:class:`CarriedKeypoints` is lib/exports/object_state.py's environment state without seeing the whole
episode: while an arm's gripper command is closed (g < 0.5) the object it closed on moves rigidly with
its pinch frame from the pose it had when the gripper closed, and stays where it was released. The
export decides which arm handles each object over the whole episode (the arm that holds it longest) and
lets a grasp carry only one of that arm's objects; online, a grasp carries the object nearest its pinch
point (by the episode's first keypoints, as the export measures it) that the other arm does not carry,
and when both arms close at the same frame the nearer (arm, object) pair is matched first (in
empty_vase the flowers' base sits inside the vase: both pinch points are nearest the vase, the holding
arm's by far). The two agree on every episode of tests/envs/test_robot_env.py (the six tasks' demonstrations,
plain and mirrored); they can differ where an arm closes first on the object the other arm will hold
longer. The arithmetic is the export's, so the values agree to float32 precision.
"""

from __future__ import annotations

import numpy as np

from demoforge.lib import geometry as geo
from demoforge.lib.exports.lerobot import ENV_STATE, IMAGE_PREFIX, features, keypoint_feature_names

STATE = "observation.state"


def export_features(keypoint_names, state_names, image: tuple[str, int, int] | None = None) -> dict:
    """{feature: {dtype, shape, names}} of the observation and the action, as the LeRobot export writes
    them (image: (camera key, width, height) of a rendered camera, dtype uint8 as decoded from the video)."""
    f = features(keypoint_feature_names(keypoint_names), state_names=list(state_names))
    out = {k: f[k] for k in (STATE, ENV_STATE, "action")}
    if image is not None:
        key, width, height = image
        out[IMAGE_PREFIX + key] = {"dtype": "uint8", "shape": [height, width, 3], "names": ["height", "width", "channels"]}
    return out


class CarriedKeypoints:
    """The object keypoints (K, 3) per frame, carried by the commanded pinch poses (see the module docstring)."""

    def __init__(self, keypoint_object: np.ndarray):
        self.ko = np.asarray(keypoint_object, int)
        self.n_obj = int(self.ko.max()) + 1

    def reset(self, keypoints0: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The first frame: keypoints0 (K, 3) the episode's keypoints, pose (2, 8) the commanded pinch poses."""
        self.kp0 = np.asarray(keypoints0, np.float64)
        self.cur = self.kp0.copy()
        self.carry: list = [None, None]  # per arm: (keypoint indices, their coordinates in the pinch frame)
        self.closed = np.zeros(2, bool)
        return self._frame(np.asarray(pose, np.float64), first=True)

    def update(self, pose: np.ndarray) -> np.ndarray:
        """The next frame's keypoints (K, 3) for the commanded pinch poses pose (2, 8)."""
        return self._frame(np.asarray(pose, np.float64), first=False)

    def _grasped(self, starting: list[int], pose: np.ndarray) -> dict[int, int]:
        """The object each arm in `starting` closes on: (arm, object) pairs by ascending distance (the episode's
        first keypoints to the pinch point), each arm and each object once, none the other arm carries."""
        taken = {int(self.ko[c[0][0]]) for a, c in enumerate(self.carry) if c is not None and a not in starting}
        pairs = []
        for arm in starting:
            d = np.linalg.norm(self.kp0 - pose[arm, None, :3], axis=-1)
            pairs += [(float(d[self.ko == o].min()), arm, o) for o in range(self.n_obj) if o not in taken]
        out: dict[int, int] = {}
        for _, arm, o in sorted(pairs):
            if arm not in out and o not in out.values():
                out[arm] = o
        return out

    def _frame(self, pose: np.ndarray, first: bool) -> np.ndarray:
        closed = pose[:, 7] < 0.5
        starting = [a for a in (0, 1) if closed[a] and (first or not self.closed[a])]
        grasped = self._grasped(starting, pose) if starting else {}
        for arm in (0, 1):
            if not closed[arm]:
                self.carry[arm] = None  # released: the object stays where it was let go
                continue
            if arm in starting:  # a grasp starts: the object in the pinch frame now
                self.carry[arm] = None
                if arm in grasped:
                    idx = np.flatnonzero(self.ko == grasped[arm])
                    R0 = geo.quat_to_matrix(pose[arm, 3:7])
                    self.carry[arm] = (idx, np.einsum("ji,kj->ki", R0, self.cur[idx] - pose[arm, None, :3]))
            if self.carry[arm] is not None:
                idx, lf = self.carry[arm]
                Rt = geo.quat_to_matrix(pose[arm, 3:7])
                moved = np.empty_like(lf)
                for a in range(3):  # the export's expression, term by term
                    moved[:, a] = Rt[a, 0] * lf[:, 0] + Rt[a, 1] * lf[:, 1] + Rt[a, 2] * lf[:, 2] + pose[arm, a]
                self.cur[idx] = moved
        self.closed = closed
        return self.cur.copy()


__all__ = ["CarriedKeypoints", "STATE", "ENV_STATE", "IMAGE_PREFIX", "export_features"]
