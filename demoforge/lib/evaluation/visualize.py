"""Drawing helpers for people: hand skeletons and keypoints over RGB frames (OpenCV, RGB in/out)."""

from __future__ import annotations

import numpy as np

from demoforge.lib.geometry import pose8_to_transform, project_points, transform_inverse, transform_points
from demoforge.lib.joints import HAND_CONNECTIONS

# One colour per finger (thumb, index, middle, ring, pinky), RGB.
FINGER_COLOURS = ((230, 60, 60), (240, 170, 30), (60, 190, 60), (40, 140, 230), (170, 70, 220))
HAND_COLOURS = {"left": (40, 200, 255), "right": (255, 120, 40)}


def _finger_of(joint: int) -> int:
    return max(0, (joint - 1) // 4)


def draw_hand(rgb: np.ndarray, joints_px: np.ndarray, visible: np.ndarray | None = None,
              side: str = "left", thickness: int = 2) -> np.ndarray:
    """Draw one 21-joint skeleton (pixels, (21, 2)) on a copy of ``rgb``; hidden joints hollow."""
    import cv2

    out = np.ascontiguousarray(rgb.copy())
    pts = np.asarray(joints_px, float)
    if not np.isfinite(pts).all():
        return out
    vis = np.ones(21, bool) if visible is None else np.asarray(visible, bool)
    for parent, child in HAND_CONNECTIONS:
        colour = FINGER_COLOURS[_finger_of(child)]
        p0 = tuple(int(round(v)) for v in pts[parent])
        p1 = tuple(int(round(v)) for v in pts[child])
        cv2.line(out, p0, p1, colour, thickness, cv2.LINE_AA)
    ring = HAND_COLOURS.get(side, (255, 255, 255))
    for j, (u, v) in enumerate(pts):
        centre = (int(round(u)), int(round(v)))
        cv2.circle(out, centre, 3, ring, -1 if vis[j] else 1, cv2.LINE_AA)
    cv2.putText(out, side[0].upper(), (int(pts[0, 0]) + 6, int(pts[0, 1]) + 6),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, ring, 1, cv2.LINE_AA)
    return out


def draw_points(rgb: np.ndarray, points_px: np.ndarray, colour=(255, 255, 0), labels=None) -> np.ndarray:
    """Draw keypoints (N, 2) as crosses, optionally numbered."""
    import cv2

    out = np.ascontiguousarray(rgb.copy())
    for i, (u, v) in enumerate(np.asarray(points_px, float)):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        c = (int(round(u)), int(round(v)))
        cv2.drawMarker(out, c, colour, cv2.MARKER_TILTED_CROSS, 9, 2, cv2.LINE_AA)
        if labels is not None:
            cv2.putText(out, str(labels[i]), (c[0] + 4, c[1] - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                        colour, 1, cv2.LINE_AA)
    return out


def montage(images: list[np.ndarray], columns: int = 3, captions: list[str] | None = None) -> np.ndarray:
    """Tile equally sized RGB images into a grid, with an optional caption on each."""
    import cv2

    if not images:
        raise ValueError("montage of no images")
    h, w = images[0].shape[:2]
    rows = -(-len(images) // columns)
    grid = np.full((rows * h, columns * w, 3), 255, np.uint8)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        tile = np.ascontiguousarray(img.copy())
        if captions:
            cv2.rectangle(tile, (0, 0), (w, 22), (0, 0, 0), -1)
            cv2.putText(tile, captions[i], (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        grid[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile
    return grid


AXIS_COLOURS = ((230, 40, 40), (40, 200, 40), (50, 90, 255))  # gripper x (closing), y, z (approach)


def draw_gripper(rgb: np.ndarray, pose8: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                 length: float = 0.04, label: str | None = None) -> np.ndarray:
    """Draw a gripper frame (world pose [x, y, z, qx, qy, qz, qw, g]) as three projected axes; the
    origin is a filled dot when open (g = 1) and a ring when closed."""
    import cv2

    out = np.ascontiguousarray(rgb.copy())
    p = np.asarray(pose8, float)
    if not np.isfinite(p).all():
        return out
    T, g = pose8_to_transform(p)
    pts_w = np.vstack([T[:3, 3], T[:3, 3] + length * T[:3, :3].T])            # origin, x, y, z tips
    pts_c = transform_points(transform_inverse(np.asarray(T_world_camera, float)), pts_w)
    if (pts_c[:, 2] <= 1e-6).any():
        return out
    uv = project_points(pts_c, K)
    o = tuple(int(round(v)) for v in uv[0])
    for k in range(3):
        cv2.line(out, o, tuple(int(round(v)) for v in uv[k + 1]), AXIS_COLOURS[k], 2, cv2.LINE_AA)
    cv2.circle(out, o, 4, (255, 255, 255), -1 if float(g) >= 0.5 else 2, cv2.LINE_AA)
    if label:
        cv2.putText(out, label, (o[0] + 6, o[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                    cv2.LINE_AA)
    return out
