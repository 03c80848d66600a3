"""The camera's pose in the table frame (``T_world_camera``) found from a take: a printed ChArUco board
on the table (:mod:`.board`), or the table plane in the depth plus two points on the table's edge
(:mod:`.plane`); :func:`calibrate` picks the frames and the method."""

from demoforge.lib.calibration.board import BoardSpec, T_world_board, fit_board, write_board_print
from demoforge.lib.calibration.calibrate import METHODS, Calibration, calibrate, draw_table_frame
from demoforge.lib.calibration.plane import (
    CalibrationError, frame_on_plane, pose_errors, rays_on_plane, table_plane,
)

__all__ = ["BoardSpec", "Calibration", "CalibrationError", "METHODS", "T_world_board", "calibrate", "draw_table_frame",
           "fit_board", "frame_on_plane", "pose_errors", "rays_on_plane", "table_plane", "write_board_print"]
