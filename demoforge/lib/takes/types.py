"""The take's types: camera, frame, annotations, the take itself, a batch of decoded frames, and the
error a bad take raises."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple
import numpy as np

from demoforge.lib.errors import UserError


#: Every value :attr:`FrameInfo.status` can take.
FRAME_STATUSES = (
    "ok", "missing_depth", "missing_rgb", "unreadable_rgb", "unreadable_depth",
    "depth_size_mismatch", "all_zero_depth",
    # recordings (demoforge.lib.takes.sources): a frame the camera's timestamps say was dropped, a frame
    # delivered twice (the copy is discarded), a frame where the camera had moved (Record3D's poses)
    "dropped_frame", "repeated_frame", "camera_moved",
)
#: Statuses for which the frame has no usable RGB (skipped by :func:`iter_frames`).
RGB_BAD = ("missing_rgb", "unreadable_rgb", "dropped_frame")

IMAGE_EXTS = (".png", ".jpg", ".jpeg")
DEPTH_EXTS = (".npy", ".png")
DEFAULT_FPS = 30.0
DEFAULT_DEPTH_SCALE = 0.001  # metres per unit of integer depth (millimetres)


class TakeError(UserError):
    """A problem with the take as a whole; the message names the file/key and how to fix it."""


# ------------------------------------------------------------------------------------------------
# data classes
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraInfo:
    """Validated contents of camera.json."""

    K: np.ndarray                 # (3, 3) float64
    width: int
    height: int
    T_world_camera: np.ndarray | None  # (4, 4) float64, camera to world; None: not calibrated yet
    fps: float = DEFAULT_FPS
    depth_scale: float = DEFAULT_DEPTH_SCALE  # metres per unit of integer depth files

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height


@dataclass
class FrameInfo:
    """One frame of a take. ``status``/``message`` are updated when decoding finds a problem."""

    index: int                    # 0-based frame index (frame number - first frame number)
    timestamp_s: float            # index / fps
    rgb_source: str | None        # image path, or "<video path>#<frame number in the video>"
    depth_source: str | None      # depth file path, or None when there is none
    status: str = "ok"
    message: str = ""

    def flag(self, status: str, message: str) -> None:
        """Record a problem; the first problem found sets the status, messages accumulate."""
        assert status in FRAME_STATUSES, status
        if self.status == "ok" or (status in RGB_BAD and self.status not in RGB_BAD):
            self.status = status
        if message and message not in self.message:
            self.message = f"{self.message}; {message}" if self.message else message

    @property
    def rgb_ok(self) -> bool:
        return self.status not in RGB_BAD


@dataclass(frozen=True)
class Annotations:
    """Parsed annotations.json (see :func:`parse_annotations`)."""

    object_keypoints_frame: int | None
    object_keypoint_names: tuple[str, ...]
    object_keypoints_uv: np.ndarray          # (k, 2) px; (0, 2) when absent
    gripper_closed_ranges: dict[str, list[tuple[int, int]]]  # {"left": [(start, end)], "right": ...}
    raw: dict = field(repr=False, default_factory=dict)
    #: the optional "task" section (demoforge.lib.takes.task_definition.TaskDefinition): task, keypoints per object, arms
    task: Any = None

    def closed_mask(self, n_frames: int) -> np.ndarray:
        """(n_frames, 2) bool: gripper closed per frame and hand (0 = left, 1 = right)."""
        out = np.zeros((n_frames, 2), bool)
        for h, side in enumerate(("left", "right")):
            for s, e in self.gripper_closed_ranges.get(side, []):
                out[max(s, 0):min(e, n_frames), h] = True
        return out


@dataclass
class Take:
    """An opened take: camera, frame index (nothing decoded yet) and annotations."""

    path: Path
    camera: CameraInfo
    frames: list[FrameInfo]
    annotations: Annotations | None
    rgb_kind: str                 # "images", "video" or "recording"
    video_path: Path | None = None
    meta: dict = field(default_factory=dict)   # take.json when present (synthetic takes)
    #: what is actually decoded for a video take (a salvaged stream when the mp4 was truncated)
    video_decode_path: Path | None = None
    notes: list[str] = field(default_factory=list)  # take-level remarks (e.g. video salvaged)
    #: the take source that opened it (demoforge.lib.takes.sources: "folder", "mp4", "record3d", ...)
    source: str = "folder"
    #: where demoforge keeps the take's camera.json / annotations.json / take.json / ground_truth: the
    #: folder itself, or a recording's side folder ``<recording>.demoforge/``
    meta_dir: Path | None = None
    #: how T_world_camera was found: "camera.json" (given), "board", "table_plane", ... (None: no pose)
    pose_method: str | None = None
    #: decodes the frames (a :class:`demoforge.lib.takes.sources.TakeDecoder`, given by the source that
    #: opened the take: a take folder's images or video, a recording)
    decoder: Any = field(default=None, repr=False)

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def fps(self) -> float:
        return self.camera.fps

    @property
    def take_id(self) -> str:
        name = self.path.name.split(".")[0] if self.rgb_kind == "recording" else self.path.name
        return str(self.meta.get("take_id") or self.meta.get("take") or name)

    @property
    def has_pose(self) -> bool:
        return self.camera.T_world_camera is not None

    @property
    def timestamps_s(self) -> np.ndarray:
        return np.array([f.timestamp_s for f in self.frames], float)

    @property
    def statuses(self) -> np.ndarray:
        return np.array([f.status for f in self.frames], dtype=object)

    def status_counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.frames:
            out[f.status] = out.get(f.status, 0) + 1
        return out

    def problems(self) -> list[FrameInfo]:
        return [f for f in self.frames if f.status != "ok"]

    @property
    def ground_truth_dir(self) -> Path:
        return (self.meta_dir or self.path) / "ground_truth"

    @property
    def has_ground_truth(self) -> bool:
        return (self.ground_truth_dir / "gt_hand_joints.parquet").is_file()


def take_task_name(take: Any, task: str | None) -> str:
    """The task a take belongs to: given explicitly, else the task section of annotations.json, else
    the synthetic take.json's, else unknown."""
    if task:
        return task
    annotated = getattr(getattr(take, "annotations", None), "task", None)  # written by `demoforge annotate`
    if annotated is not None:
        return annotated.name
    return str((take.meta or {}).get("task") or "unknown")


class FrameBatch(NamedTuple):
    """A batch from :func:`iter_frames`; unpacks as ``indices, rgb, depth``."""

    indices: np.ndarray   # (B,) int64 frame indices
    rgb: np.ndarray       # (B, H, W, 3) uint8, RGB order
    depth: np.ndarray     # (B, H, W) float32 metres, invalid = 0
