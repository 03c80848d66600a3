"""Reading takes (real RGB-D recordings and synthetic takes) and external keypoint files."""

from lib.ingest.take_reader import (  # noqa: F401
    FRAME_STATUSES, Annotations, CameraInfo, FrameBatch, FrameInfo, Take, TakeError, ThesisHand,
    frame_number, iter_depth, iter_frames, open_take, parse_annotations, parse_camera, read_frame,
    read_thesis_keypoints_json,
)

__all__ = [
    "FRAME_STATUSES", "Annotations", "CameraInfo", "FrameBatch", "FrameInfo", "Take", "TakeError",
    "ThesisHand", "frame_number", "iter_depth", "iter_frames", "open_take", "parse_annotations", "parse_camera",
    "read_frame", "read_thesis_keypoints_json",
]
