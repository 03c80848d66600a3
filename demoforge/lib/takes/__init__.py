"""Takes: reading RGB-D recordings (real and synthetic: frames, depth, camera.json, annotations.json,
MP4 repair, the thesis code's keypoint JSON) in ``reader``, and annotating them (``annotate``: the
task definition, annotations.json, the open/close suggestion)."""

from demoforge.lib.takes.types import FRAME_STATUSES, Annotations, CameraInfo, take_task_name  # noqa: F401
from demoforge.lib.takes.reader import (
    FrameBatch, FrameInfo, Take, TakeError, iter_depth, iter_frames, open_take, parse_annotations,
    parse_camera, read_frame,
)
from demoforge.lib.takes.thesis_json import ThesisHand, read_thesis_keypoints_json
from demoforge.lib.takes.media import frame_number

__all__ = [
    "FRAME_STATUSES", "Annotations", "CameraInfo", "FrameBatch", "FrameInfo", "Take", "TakeError",
    "ThesisHand", "frame_number", "iter_depth", "iter_frames", "open_take", "parse_annotations", "parse_camera",
    "read_frame", "read_thesis_keypoints_json", "take_task_name",
]
