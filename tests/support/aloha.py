"""The ALOHA arms at fixed bases, and their forward kinematics, for the arm tests (so those tests do not
move when the per-task placement, aloha/placement.py, is retuned)."""

import math

import numpy as np
from scipy.spatial.transform import Rotation

from demoforge.lib.sim.robots.aloha import AlohaRobot
from demoforge.lib.sim.robots.aloha.model import BasePose

BASE = BasePose(-0.35, -0.05, 0.0, math.pi / 2)
ARMS = AlohaRobot(hand="aloha", bases=(BASE, BASE.mirrored()))
ARMS_2F140 = AlohaRobot(hand="2f140", bases=(BASE, BASE.mirrored()))


def fk(robot, q: np.ndarray) -> np.ndarray:
    """(n, 2, 8) pinch poses [x y z qx qy qz qw g=1] of joint configurations q (n, 12), from the IK's model."""
    ik = robot.ik("pouring")
    out = np.ones((len(q), 2, 8))
    for t, qt in enumerate(q):
        ik.cfg.update(qt)
        d = ik.cfg.data
        out[t, :, :3] = d.site_xpos[ik.sites]
        out[t, :, 3:7] = Rotation.from_matrix(d.site_xmat[ik.sites].reshape(2, 3, 3)).as_quat()
    return out
