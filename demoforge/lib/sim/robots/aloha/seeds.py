"""Starting configurations for the IK's first step of an episode, from the ViperX's geometry.

The ViperX 300 6-DOF is a waist, a planar shoulder-elbow pair and a roll-pitch-roll wrist whose axes
meet the forearm's axis. So a pinch pose fixes the wrist centre (the wrist-angle joint: the pinch point
moved back along the approach axis by the wrist-to-pinch length); the waist turns towards it, the
shoulder and elbow are a two-link triangle (elbow up or down), and the wrist's three angles are the
roll-pitch-roll (XYX) Euler angles of what remains of the rotation. With the wrist's two branches that
is up to four exact solutions (the links' small offsets aside); mink then refines the best one within
the joint limits (lib/sim/robots/ik.py). Without these seeds the first step started from a folded
rest pose and often stopped in a local minimum centimetres away.
"""

from __future__ import annotations

import math

import numpy as np

from .model import LINK_TO_GRIPPER, BasePose


class ViperXGeometry:
    """The link offsets of one arm, read from the kinematic model (bodies `<side>_...`)."""

    def __init__(self, model, side: str = "left"):
        pos = {n: np.array(model.body(f"{side}_{n}").pos) for n in
               ("shoulder_link", "upper_arm_link", "upper_forearm_link", "lower_forearm_link", "wrist_link",
                "gripper_link", "hand")}
        self.shoulder_z = float(pos["shoulder_link"][2] + pos["upper_arm_link"][2])
        upper = pos["upper_forearm_link"]  # (x offset, 0, length) in the upper arm's frame
        self.l1 = float(math.hypot(upper[0], upper[2]))
        self.alpha = float(math.atan2(upper[0], upper[2]))  # the upper arm's tilt forward at shoulder = 0
        self.l2 = float(pos["lower_forearm_link"][0] + pos["wrist_link"][0])
        self.wrist_to_pinch = float(pos["gripper_link"][0] + pos["hand"][0])

    def solutions(self, base: BasePose, pose: np.ndarray) -> list[np.ndarray]:
        """Joint angles (6,) putting the pinch frame at pose [x y z qx qy qz qw] (world), as far as the
        triangle closes (a target out of reach: the arm stretched towards it)."""
        from scipy.spatial.transform import Rotation

        T = base.matrix()
        R_hand = T[:3, :3].T @ Rotation.from_quat(pose[3:7]).as_matrix()  # in the base frame
        R_link = R_hand @ LINK_TO_GRIPPER.T  # the gripper link's axes (x = approach)
        p = T[:3, :3].T @ (np.asarray(pose[:3], float) - T[:3, 3])
        w = p - self.wrist_to_pinch * R_link[:, 0]
        waist = math.atan2(w[1], w[0])
        r, h = math.hypot(w[0], w[1]), w[2] - self.shoulder_z
        out = []
        for reach, turn in ((r, waist), (-r, waist + math.pi)):  # facing the wrist centre, or leaning over backwards
            turn = math.atan2(math.sin(turn), math.cos(turn))
            d2 = reach * reach + h * h
            c = (d2 - self.l1 ** 2 - self.l2 ** 2) / (2 * self.l1 * self.l2)
            for delta in (math.acos(min(1.0, max(-1.0, c))), -math.acos(min(1.0, max(-1.0, c)))):
                psi1 = math.atan2(reach, h) - math.atan2(self.l2 * math.sin(delta), self.l1 + self.l2 * math.cos(delta))
                shoulder = psi1 - self.alpha
                elbow = self.alpha + delta - math.pi / 2
                R_fore = Rotation.from_euler("ZY", [turn, shoulder + elbow]).as_matrix()
                roll, pitch, roll2 = Rotation.from_matrix(R_fore.T @ R_link).as_euler("XYX")
                out.append(np.array([turn, shoulder, elbow, roll, pitch, roll2]))
        return out
