"""A minimal stand-in scene (a cup and a bowl) and demonstration (two hands pinching) for rendering a
synthetic take without the task library."""

from collections import namedtuple

import numpy as np

Segment = namedtuple("Segment", "arm kind start end object")

STANDIN_XML = """
<mujoco model="standin">
  <asset><material name="wood" rgba="0.55 0.42 0.30 1"/></asset>
  <worldbody>
    <light pos="0 0.2 1.5" dir="0 0 -1" directional="true" diffuse="0.7 0.7 0.7"/>
    <geom name="table" type="box" size="1.2 1.0 0.02" pos="0 0.30 -0.02" material="wood"/>
    <body name="cup" pos="0.15 0.30 0.05"><freejoint/>
      <geom type="cylinder" size="0.035 0.05" rgba="0.15 0.35 0.80 1"/></body>
    <body name="bowl" pos="-0.15 0.30 0.03"><freejoint/>
      <geom type="cylinder" size="0.07 0.03" rgba="0.20 0.65 0.25 1"/></body>
  </worldbody>
</mujoco>
"""


class StandInDemo:
    """Two hands approaching a cup and a bowl from above, pinching as they go (n frames)."""

    def __init__(self, n: int = 6):
        self.fps = 30.0
        self.placement = {"standin": True}
        s = np.linspace(0, 1, n)
        T = np.tile(np.eye(4), (n, 2, 1, 1))
        for h, sx in ((0, -1.0), (1, 1.0)):
            z = np.array([0.0, 0.6, -1.0]) / np.linalg.norm([0.0, 0.6, -1.0])
            x = np.array([sx, 0.0, 0.0])
            y = np.cross(z, x)
            T[:, h, :3, 0], T[:, h, :3, 1], T[:, h, :3, 2] = x, y, z
            T[:, h, 0, 3] = sx * (0.15 + 0.05 * (1 - s))
            T[:, h, 1, 3] = 0.22 + 0.06 * s
            T[:, h, 2, 3] = 0.20 - 0.08 * s
        self.pinch_poses = T
        self.aperture = np.stack([0.08 - 0.06 * s, 0.09 - 0.05 * s], axis=1)
        self.closed = np.zeros((n, 2), bool)
        self.closed[n // 2:, 1] = True
        self.held_object = np.where(self.closed, np.array([1, 0]), -1)
        P = np.tile(np.eye(4), (n, 2, 1, 1))
        P[:, 0, :3, 3] = [0.15, 0.30, 0.05]
        P[:, 1, :3, 3] = [-0.15, 0.30, 0.03]
        self.object_poses = P
        self.segments = [Segment(0, "motion", 0, n, "bowl"), Segment(1, "motion", 0, n // 2, 0),
                         Segment(1, "skill", n // 2, n, None)]

    def keypoints(self) -> np.ndarray:
        n = len(self.pinch_poses)
        off = np.array([[dx, dy, dz] for dx in (-0.03, 0.0, 0.03) for dy in (-0.03, 0.03) for dz in (0.0,)]
                       + [[0, 0, 0.05]] * 5)[:11]
        base = np.where(np.arange(11)[:, None] < 6, self.object_poses[:, :1, :3, 3], self.object_poses[:, 1:, :3, 3])
        return base + off[None]

