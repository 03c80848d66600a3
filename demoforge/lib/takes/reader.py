"""Read a take folder (real recording or synthetic take) without decoding all of it up front.

Take folder layout (the same for a real RGB-D recording and for :mod:`demoforge.lib.synth.take`)::

    <take>/
      rgb/000000.png ...     RGB frames, PNG or JPG, ordered by the number in the file name
      rgb.mp4                or a video instead of rgb/ (rgb.mp4, or the only *.mp4 in the folder)
      depth/000000.npy ...   depth per frame: .npy float (metres; an integer .npy is millimetres) or a
                             16-bit PNG in millimetres. 0 or NaN (or negative / inf) = invalid.
      camera.json            {"K": 3x3, "width": W, "height": H, "T_world_camera": 4x4 camera-to-world,
                              "fps": 30.0 (optional, default 30),
                              "depth_unit": "m" | "mm" (optional), "depth_scale": metres per unit
                              of integer depth (optional; default 0.001)}
      annotations.json       optional, see :func:`parse_annotations` (format of lib/synth/take.py)
      ground_truth/          only for synthetic takes

Frames are paired by the number in the file name (``rgb/000017.png`` with ``depth/000017.npy``);
frame index = number - smallest number, so a dropped file leaves a flagged frame, not a shift.
Without numbers in the names, frames are paired by sorted position.

Per-frame problems never raise: :class:`FrameInfo` ``status`` is one of :data:`FRAME_STATUSES` and
``message`` says what is wrong. Cheap checks (missing files, depth shape from the .npy / PNG
header) are made by :func:`open_take`; decoding problems (unreadable file, all-zero depth,
truncated video) are found by :func:`iter_frames` / :func:`read_frame`, which update the frame's
status in place. Policy of :func:`iter_frames`: a frame whose RGB cannot be had is skipped; a frame
whose depth cannot be had is yielded with all-invalid (zero) depth.

Every take decodes the same way: the source that opened it (demoforge.lib.takes.sources: a take folder's
images or video, a recording) gave it its decoder (``Take.decoder``, a
:class:`demoforge.lib.takes.sources.TakeDecoder`), and these functions only ask it.

Problems with the take as a whole (no camera.json, a bad K or T_world_camera, no frames at all,
RGB of another size than camera.json, malformed annotations) raise :class:`TakeError`, whose
message names the file and key and says how to fix it.

It also reads the keypoint JSON of the thesis's public code (Jiayun-Zhang/Hand_keypoint_detector,
``run.py``): :func:`read_thesis_keypoints_json`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator, Sequence
import numpy as np

from demoforge.lib.takes.metadata import parse_annotations, parse_camera  # noqa: F401  (re-exported)
from demoforge.lib.takes.sources import source_for
from demoforge.lib.takes.types import CameraInfo, FrameBatch, FrameInfo, Take, TakeError  # noqa: F401  (re-exported)


def open_take(path: str | os.PathLike, *, prefer: str = "images",
              cache_dir: str | os.PathLike | None = None, require_pose: bool = True, **options) -> Take:
    """Open a take: a take folder, or a recording file or folder (demoforge.lib.takes.sources: the
    first registered source that claims the path opens it). Validates camera.json / annotations.json
    and indexes the frames; nothing is decoded yet.

    Args:
        path: the take folder, or a recording (RealSense .bag/.db3, Record3D .r3d or export folder,
            ROS 2 bag .mcap/.db3 or its folder, a take folder's .mp4).
        prefer: for a take folder, ``"images"`` (default) uses ``rgb/`` when both ``rgb/`` and a video
            exist; ``"video"`` uses the video.
        cache_dir: where a truncated mp4's recovered stream is written (default: a temporary
            folder). A truncated mp4 whose index survived decodes up to the cut; one whose index was
            lost (OpenCV writes it last) is recovered by :func:`salvage_mp4` when it is mp4v.
        require_pose: raise when the camera's pose (T_world_camera) is unknown; False opens such a
            take with ``camera.T_world_camera`` None (to calibrate it).
        options: source options (a ROS 2 bag's ``rgb_topic``, ``depth_topic``, ``info_topic``).

    Raises:
        TakeError: no such path, not a take, missing or invalid camera.json, no frames, RGB size
            different from camera.json, malformed annotations.json, a recording that cannot be read.
    """
    root = Path(path)
    return source_for(root)().open(root, require_pose=require_pose, prefer=prefer, cache_dir=cache_dir, **options)


# ------------------------------------------------------------------------------------------------
# decoding: the take's decoder (its source's) does it
# ------------------------------------------------------------------------------------------------

def _decoder(take: Take):
    if take.decoder is None:
        raise ValueError(f"take {take.path} has no decoder: open it with open_take")
    return take.decoder


def iter_frames(take: Take, batch_size: int = 16, *, frames: Sequence[int] | None = None,
                num_workers: int = 2) -> Iterator[FrameBatch]:
    """Decode frames in batches: yields :class:`FrameBatch` (indices, rgb uint8 RGB, depth float32 m).

    Frames whose RGB is missing or cannot be decoded are skipped (and flagged on ``take.frames``);
    frames whose depth is missing or bad get all-zero depth (flagged). Never raises for one bad
    frame. ``frames`` restricts to these indices (in increasing order); ``num_workers`` threads
    decode image files in parallel (OpenCV releases the GIL).
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    idx = list(range(take.n_frames)) if frames is None else sorted(set(int(i) for i in frames))
    for i in idx:
        if not 0 <= i < take.n_frames:
            raise IndexError(f"frame {i} out of range: take has {take.n_frames} frames")
    idx = [i for i in idx if take.frames[i].rgb_ok]
    for group in _decoder(take).rgbd(take, idx, batch_size, num_workers):
        yield FrameBatch(np.array([g[0] for g in group], np.int64), np.stack([g[1] for g in group]),
                         np.stack([g[2] for g in group]))


def iter_depth(take: Take, batch_size: int = 32, *, num_workers: int = 2
               ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Depth only, every frame in order: yields (indices (B,), depth float32 (B, H, W) m, invalid = 0).

    Frames without usable depth come as all-zero (and are flagged on ``take.frames``), so the
    batches cover the whole take whatever the state of its RGB.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    yield from _decoder(take).depth(take, batch_size, num_workers)


def read_frame(take: Take, index: int) -> tuple[np.ndarray | None, np.ndarray]:
    """One frame: (rgb uint8 (H, W, 3) or None if unusable, depth float32 metres, invalid = 0)."""
    for b in iter_frames(take, batch_size=1, frames=[index], num_workers=1):
        return b.rgb[0], b.depth[0]
    return None, _decoder(take).lone_depth(take, index)
