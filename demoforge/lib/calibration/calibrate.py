"""`demoforge calibrate`: the camera's pose in the table frame from a take, by a board or the table plane."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from demoforge.lib.calibration.board import BoardSpec, T_world_board, fit_board
from demoforge.lib.calibration.plane import CalibrationError, frame_on_plane, median_depth, rays_on_plane, table_plane
from demoforge.lib.geometry import project_points, transform_inverse, transform_points
from demoforge.lib.takes.reader import iter_frames
from demoforge.lib.takes.types import Take

METHODS = ("auto", "board", "plane")


@dataclass
class Calibration:
    T_world_camera: np.ndarray
    method: str                     # "board", "table_plane" or "table_plane+edge"
    details: dict = field(default_factory=dict)
    frames: list = field(default_factory=list, repr=False)   # (index, rgb) used, for the preview


def pick_frames(take: Take, n: int) -> list[int]:
    """Up to ``n`` frames spread over the take (the camera is static; hands move out of the way)."""
    usable = [f.index for f in take.frames if f.rgb_ok]
    if not usable:
        raise CalibrationError(f"{take.path}: no readable frame to calibrate from")
    pos = np.unique(np.linspace(0, len(usable) - 1, min(n, len(usable))).round().astype(int))
    return [usable[i] for i in pos]


def calibrate(take: Take, method: str = "auto", board: BoardSpec | None = None,
              board_origin: Sequence[float] = (0.0, 0.0), edge_clicks: np.ndarray | None = None,
              frames: int = 8) -> Calibration:
    """The camera's pose from ``frames`` frames of the take: a ChArUco board on the table (``board``),
    the table plane in the depth (``plane``, with the robot-side edge's two clicked pixels
    ``edge_clicks`` (2, 2) when given), or the board when it is seen, else the plane (``auto``)."""
    if method not in METHODS:
        raise CalibrationError(f"unknown calibration method {method!r}; choose one of {', '.join(METHODS)}")
    spec = board or BoardSpec()
    idx = pick_frames(take, frames)
    got = [(int(i), rgb, depth) for b in iter_frames(take, batch_size=4, frames=idx)
           for i, rgb, depth in zip(b.indices, b.rgb, b.depth)]
    if method in ("auto", "board") and edge_clicks is None:
        fit = fit_board([(i, rgb) for i, rgb, _ in got], take.K, spec)
        if fit is not None:
            T = T_world_board(spec, board_origin) @ np.linalg.inv(fit.T_camera_board)
            return Calibration(T, "board", {
                "board": spec.to_json(), "board_origin_xy": [float(x) for x in board_origin],
                "frames_used": fit.frames_used, "corners": fit.corners,
                "reprojection_px": round(fit.reprojection_px, 3)}, [(i, r) for i, r, _ in got])
        if method == "board":
            raise CalibrationError(
                f"{take.path}: no ChArUco board ({spec.squares_x}x{spec.squares_y}, {spec.dictionary}) in view in "
                f"frames {idx[0]}..{idx[-1]}; lay the printed board (demoforge calibrate --print-board) flat on the "
                f"table where the camera sees it, check --board/--square-mm/--dictionary, or use --method plane")
    depth = median_depth([d for _, _, d in got])
    plane = table_plane(depth, take.K)
    edge = None
    if edge_clicks is not None:
        edge = rays_on_plane(np.asarray(edge_clicks, float).reshape(2, 2), take.K, plane.normal, plane.height_m)
    T = frame_on_plane(plane.normal, plane.height_m, edge)
    details = {"height_m": round(plane.height_m, 5), "inlier_fraction": round(plane.inlier_fraction, 4),
               "plane_rms_mm": round(plane.rms_m * 1000, 3), "points": plane.points, "frames_used": idx,
               "axes": "from the two edge clicks" if edge is not None else "y = the camera's forward direction"}
    if edge_clicks is not None:
        details["edge_clicks_px"] = np.asarray(edge_clicks, float).reshape(2, 2).tolist()
    return Calibration(T, "table_plane+edge" if edge is not None else "table_plane", details,
                       [(i, r) for i, r, _ in got])


def draw_table_frame(rgb: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray, grid_m: float = 0.1,
                     extent_m: float = 0.5) -> np.ndarray:
    """The frame with the table frame drawn on it: a 10 cm grid on the table, x red, y green, z blue."""
    import cv2

    img = np.ascontiguousarray(rgb).copy()
    T_cw = transform_inverse(np.asarray(T_world_camera, float))

    def line(a, b, colour, width):
        pc = transform_points(T_cw, np.array([a, b], float))
        if (pc[:, 2] <= 0.05).any():
            return
        uv = project_points(pc, np.asarray(K, float))
        cv2.line(img, tuple(int(round(x)) for x in uv[0]), tuple(int(round(x)) for x in uv[1]), colour, width,
                 cv2.LINE_AA)

    ticks = np.arange(-extent_m, extent_m + 1e-9, grid_m)
    for t in ticks:
        line((t, -extent_m, 0), (t, extent_m, 0), (255, 255, 255), 1)
        line((-extent_m, t, 0), (extent_m, t, 0), (255, 255, 255), 1)
    for axis, colour in ((0, (255, 0, 0)), (1, (0, 200, 0)), (2, (0, 0, 255))):
        end = np.zeros(3)
        end[axis] = 0.15
        line((0, 0, 0), end, colour, 3)
    return img
