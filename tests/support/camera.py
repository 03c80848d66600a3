"""Camera poses for the tests."""

import numpy as np


def look_at(eye, target) -> np.ndarray:
    """camera-to-world of an OpenCV camera at ``eye`` looking at ``target`` (world z up)."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T

