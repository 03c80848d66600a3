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

Problems with the take as a whole (no camera.json, a bad K or T_world_camera, no frames at all,
RGB of another size than camera.json, malformed annotations) raise :class:`TakeError`, whose
message names the file and key and says how to fix it.

It also reads the keypoint JSON of the thesis's public code (Jiayun-Zhang/Hand_keypoint_detector,
``run.py``): :func:`read_thesis_keypoints_json`.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Iterator, Sequence
import numpy as np

from demoforge.lib.takes.types import CameraInfo, FrameBatch, FrameInfo, Take, TakeError
from demoforge.lib.takes.metadata import parse_annotations, parse_camera  # noqa: F401  (re-exported)


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
    from demoforge.lib.takes.sources import source_for

    root = Path(path)
    cls = source_for(root)
    if cls.name in ("folder", "mp4"):
        return cls().open(root, require_pose=require_pose, prefer=prefer, cache_dir=cache_dir)
    return cls().open(root, require_pose=require_pose, **options)


# ------------------------------------------------------------------------------------------------
# decoding
# ------------------------------------------------------------------------------------------------

def _decode_rgb_image(path: str, camera: CameraInfo) -> tuple[np.ndarray | None, str]:
    import cv2

    try:
        buf = np.fromfile(path, dtype=np.uint8)
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    except Exception as e:  # noqa: BLE001
        return None, f"{Path(path).name}: {e}"
    if img is None:
        return None, f"{Path(path).name}: cannot be decoded as an image (corrupt or truncated)"
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        return None, f"{Path(path).name}: unsupported image dtype {img.dtype}"
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if img.shape[:2] != (camera.height, camera.width):
        return None, (f"{Path(path).name} is {img.shape[1]} x {img.shape[0]}, camera.json says "
                      f"{camera.width} x {camera.height}")
    return img, ""


def _decode_depth(f: FrameInfo, camera: CameraInfo) -> np.ndarray:
    """Depth in metres (float32, invalid = 0); flags the frame on any problem (all-invalid then)."""
    import cv2

    shape = (camera.height, camera.width)
    zeros = np.zeros(shape, np.float32)
    if f.depth_source is None or f.status in ("unreadable_depth", "depth_size_mismatch"):
        return zeros
    p = Path(f.depth_source)
    try:
        if p.suffix.lower() == ".npy":
            d = np.load(p, allow_pickle=False)
        else:
            buf = np.fromfile(p, dtype=np.uint8)
            d = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
            if d is None:
                f.flag("unreadable_depth", f"{p.name}: cannot be decoded as a PNG (corrupt or truncated)")
                return zeros
    except Exception as e:  # noqa: BLE001 - any read problem is a per-frame problem
        f.flag("unreadable_depth", f"{p.name}: {type(e).__name__}: {e}")
        return zeros
    d = np.asarray(d)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[..., 0]
    if d.ndim != 2:
        f.flag("unreadable_depth", f"{p.name}: depth must be a 2D array, got shape {d.shape}")
        return zeros
    if d.shape != shape:
        f.flag("depth_size_mismatch", f"{p.name} has shape {d.shape}, camera.json says (height, width) = {shape}")
        return zeros
    if np.issubdtype(d.dtype, np.integer):
        # integer depth (16-bit PNG or integer .npy): units of depth_scale metres (default mm)
        m = d.astype(np.float32) * np.float32(camera.depth_scale)
    elif np.issubdtype(d.dtype, np.floating):
        m = d.astype(np.float32, copy=False)
    else:
        f.flag("unreadable_depth", f"{p.name}: unsupported depth dtype {d.dtype}")
        return zeros
    m = np.where(np.isfinite(m) & (m > 0), m, np.float32(0.0)).astype(np.float32, copy=False)
    if not m.any():
        f.flag("all_zero_depth", f"{p.name}: no valid depth pixel (all 0 / NaN)")
    return m


def _iter_video(take: Take, wanted: set[int]) -> Iterator[tuple[int, np.ndarray | None]]:
    """Decode the video sequentially; yields (index, rgb or None) for wanted frames of the container."""
    import cv2

    cap = cv2.VideoCapture(str(take.video_decode_path or take.video_path))
    try:
        if not cap.isOpened():
            for i in sorted(wanted):
                yield i, None
            return
        last = max(wanted) if wanted else -1
        i = 0
        while i <= last:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            if i in wanted:
                yield i, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            i += 1
        for j in sorted(w for w in wanted if w >= i):
            yield j, None
    finally:
        cap.release()


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
    cam = take.camera
    idx = list(range(take.n_frames)) if frames is None else sorted(set(int(i) for i in frames))
    for i in idx:
        if not 0 <= i < take.n_frames:
            raise IndexError(f"frame {i} out of range: take has {take.n_frames} frames")
    idx = [i for i in idx if take.frames[i].rgb_ok]

    def load_depth(i: int) -> np.ndarray:
        return _decode_depth(take.frames[i], cam)

    def emit(buf: list[tuple[int, np.ndarray, np.ndarray]]) -> FrameBatch:
        return FrameBatch(np.array([b[0] for b in buf], np.int64), np.stack([b[1] for b in buf]),
                          np.stack([b[2] for b in buf]))

    if take.decoder is not None:
        yield from _batches(_recording_frames(take, idx), emit, batch_size)
        return
    pool = ThreadPoolExecutor(max_workers=max(1, num_workers)) if num_workers > 1 else None
    try:
        if take.rgb_kind == "video":
            buf: list = []
            for i, rgb in _iter_video(take, set(idx)):
                f = take.frames[i]
                if rgb is None:
                    f.flag("unreadable_rgb", f"frame {i} of {take.video_path.name} could not be decoded "
                                             f"(video truncated or corrupt)")
                    continue
                if rgb.shape[:2] != (cam.height, cam.width):
                    f.flag("unreadable_rgb", f"video frame {i} is {rgb.shape[1]} x {rgb.shape[0]}, camera.json "
                                             f"says {cam.width} x {cam.height}")
                    continue
                buf.append((i, rgb, load_depth(i)))
                if len(buf) == batch_size:
                    yield emit(buf)
                    buf = []
            if buf:
                yield emit(buf)
            return

        def load(i: int):
            f = take.frames[i]
            rgb, msg = _decode_rgb_image(f.rgb_source, cam)
            if rgb is None:
                f.flag("unreadable_rgb", msg)
                return None
            return i, rgb, load_depth(i)

        for start in range(0, len(idx), batch_size):
            chunk = idx[start:start + batch_size]
            got = list(pool.map(load, chunk)) if pool is not None else [load(i) for i in chunk]
            got = [g for g in got if g is not None]
            if got:
                yield emit(got)
    finally:
        if pool is not None:
            pool.shutdown(wait=True)


def _batches(items: Iterator[tuple[int, np.ndarray, np.ndarray]], emit, batch_size: int) -> Iterator[FrameBatch]:
    buf: list = []
    for item in items:
        buf.append(item)
        if len(buf) == batch_size:
            yield emit(buf)
            buf = []
    if buf:
        yield emit(buf)


def _recording_depth(f: FrameInfo, depth: np.ndarray | None, camera: CameraInfo, msg: str) -> np.ndarray:
    """A recording's decoded depth checked as a depth file is: right size, valid values, not all zero."""
    shape = (camera.height, camera.width)
    if depth is None:
        f.flag("unreadable_depth" if msg else "missing_depth", msg or f"frame {f.index}: no depth frame")
        return np.zeros(shape, np.float32)
    if depth.shape != shape:
        f.flag("depth_size_mismatch", f"frame {f.index}: depth is {depth.shape[1]} x {depth.shape[0]}, the RGB "
                                      f"{camera.width} x {camera.height}")
        return np.zeros(shape, np.float32)
    m = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32, copy=False)
    if not m.any():
        f.flag("all_zero_depth", f"frame {f.index}: no valid depth pixel (all 0 / NaN)")
    return m


def _recording_frames(take: Take, idx: list[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """A recording's frames streamed by its decoder; a frame without usable RGB is flagged and skipped."""
    for i, rgb, depth, msg in take.decoder.frames(idx):
        f = take.frames[i]
        if rgb is None:
            f.flag("unreadable_rgb", msg or f"frame {i}: colour frame cannot be decoded")
            continue
        yield i, rgb, _recording_depth(f, depth, take.camera, msg)


def iter_depth(take: Take, batch_size: int = 32, *, num_workers: int = 2
               ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Depth only, every frame in order: yields (indices (B,), depth float32 (B, H, W) m, invalid = 0).

    Frames without usable depth come as all-zero (and are flagged on ``take.frames``), so the
    batches cover the whole take whatever the state of its RGB.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    idx = np.arange(take.n_frames)
    if take.decoder is not None:
        yield from _recording_depth_batches(take, batch_size)
        return

    def load(i: int) -> np.ndarray:
        return _decode_depth(take.frames[int(i)], take.camera)

    with ThreadPoolExecutor(max_workers=max(1, num_workers)) as pool:
        for start in range(0, len(idx), batch_size):
            chunk = idx[start:start + batch_size]
            yield chunk, np.stack(list(pool.map(load, chunk)))


def _recording_depth_batches(take: Take, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    cam = take.camera
    zeros = np.zeros((cam.height, cam.width), np.float32)
    decoded = iter(take.decoder.frames(list(range(take.n_frames))))
    pending = next(decoded, None)
    for start in range(0, take.n_frames, batch_size):
        chunk = np.arange(start, min(start + batch_size, take.n_frames))
        out = []
        for i in chunk:
            f = take.frames[int(i)]
            if pending is not None and pending[0] == i:
                out.append(_recording_depth(f, pending[2], cam, pending[3]))
                pending = next(decoded, None)
            else:
                out.append(zeros)
                if f.status == "ok":
                    f.flag("missing_depth", f"frame {i}: no depth frame")
        yield chunk, np.stack(out)


def read_frame(take: Take, index: int) -> tuple[np.ndarray | None, np.ndarray]:
    """One frame: (rgb uint8 (H, W, 3) or None if unusable, depth float32 metres, invalid = 0)."""
    for b in iter_frames(take, batch_size=1, frames=[index], num_workers=1):
        return b.rgb[0], b.depth[0]
    if take.decoder is not None:
        return None, np.zeros((take.camera.height, take.camera.width), np.float32)
    return None, _decode_depth(take.frames[index], take.camera)
