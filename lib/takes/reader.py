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

import json
import os
import re
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Iterator, Sequence
import numpy as np

from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.lib.takes.types import DEPTH_EXTS, FrameBatch, FrameInfo, IMAGE_EXTS, Take, TakeError
from demoforge.lib.takes.metadata import _load_json, parse_annotations, parse_camera
from demoforge.lib.takes.media import (
    _find_video, _image_header_size, _list_files, _npy_header, _numbered, _png_size, _salvage_mp4,
    _video_props,
)


def open_take(path: str | os.PathLike, *, prefer: str = "images",
              cache_dir: str | os.PathLike | None = None) -> Take:
    """Open a take folder: validate camera.json / annotations.json and index the frames.

    Args:
        path: the take folder.
        prefer: ``"images"`` (default) uses ``rgb/`` when both ``rgb/`` and a video exist;
            ``"video"`` uses the video.
        cache_dir: where a truncated mp4's recovered stream is written (default: a temporary
            folder). A truncated mp4 whose index survived decodes up to the cut; one whose index was
            lost (OpenCV writes it last) is recovered by :func:`_salvage_mp4` when it is mp4v.

    Raises:
        TakeError: no such folder, missing or invalid camera.json, no frames, RGB size different
            from camera.json, malformed annotations.json.
    """
    root = Path(path)
    if not root.is_dir():
        raise TakeError(f"{root}: take folder does not exist (expected rgb/ or rgb.mp4, depth/, camera.json)")
    cam_path = root / "camera.json"
    if not cam_path.is_file():
        raise TakeError(f"{cam_path}: camera.json is missing; write it with K (3x3), width, height and "
                        f"T_world_camera (4x4 camera-to-world) (fps optional, default 30)")
    camera = parse_camera(_load_json(cam_path, "camera.json"), cam_path)

    rgb_files = sorted(_list_files(root / "rgb", IMAGE_EXTS))
    video = None
    if prefer not in ("images", "video"):
        raise ValueError(f"prefer must be 'images' or 'video', got {prefer!r}")
    if not rgb_files or prefer == "video":
        try:
            video = _find_video(root)
        except TakeError:
            if not rgb_files:
                raise
    if video is not None:
        rgb_files = []
    depth_files = sorted(_list_files(root / "depth", DEPTH_EXTS))

    rgb_map: dict[int, str] = {}
    video_note = ""
    decode_path = video
    notes: list[str] = []
    if video is not None:
        props = _video_props(video)
        if props is None:
            where = Path(cache_dir) if cache_dir is not None else folder_removed_at_exit("demoforge_video_")
            salv = _salvage_mp4(video, camera, where)
            if salv is not None:
                decode_path, n_ok = salv
                props = (n_ok, camera.width, camera.height)
                video_note = (f"{video.name} is truncated (its index is missing); {n_ok} complete frames "
                              f"recovered, the rest of the video is lost")
                notes.append(video_note)
            else:
                if cache_dir is None:
                    shutil.rmtree(where, ignore_errors=True)
                video_note = (f"{video.name} cannot be opened by OpenCV (truncated or corrupt file: its index "
                              f"may be missing); re-export the video or provide rgb/ frames")
                notes.append(video_note)
        if props is None:
            n_video = 0
        else:
            n_video, vw, vh = props
            if (vw, vh) != (camera.width, camera.height) and vw > 0:
                raise TakeError(f"{cam_path}: width x height = {camera.width} x {camera.height} but {video.name} "
                                f"is {vw} x {vh}; fix camera.json (and K) to the video's size")
            rgb_map = {i: f"{video}#{i}" for i in range(n_video)}
    else:
        numbered = _numbered(rgb_files, "rgb", root / "rgb")
        if numbered is None:
            numbered = {i: p for i, p in enumerate(sorted(rgb_files, key=lambda p: p.name))}
        first = min(numbered) if numbered else 0
        rgb_map = {n - first: str(p) for n, p in numbered.items()}
        if rgb_files:
            p0 = numbered[first]
            size = _image_header_size(p0)
            if size is not None and size != (camera.width, camera.height):
                raise TakeError(f"{cam_path}: width x height = {camera.width} x {camera.height} but {p0.name} is "
                                f"{size[0]} x {size[1]}; fix camera.json (and K) to the frames' size")

    depth_numbered = _numbered(depth_files, "depth", root / "depth")
    if depth_numbered is None:
        depth_map = {i: str(p) for i, p in enumerate(sorted(depth_files, key=lambda p: p.name))}
    else:
        if video is None and rgb_files:
            first = min(n for n in (_numbered(rgb_files, "rgb", root / "rgb") or {0: None}))
        else:
            first = min(depth_numbered) if depth_numbered else 0
        depth_map = {n - first: str(p) for n, p in depth_numbered.items()}

    if not rgb_map and not depth_map:
        raise TakeError(f"{root}: no frames found: need rgb/ with .png/.jpg frames or an .mp4 video, and depth/"
                        + (f" ({video_note})" if video_note else ""))
    keys = set(rgb_map) | set(depth_map)
    lo, hi = min(keys), max(keys)
    if lo < 0:
        keys_sorted = sorted(keys)
        remap = {k: i for i, k in enumerate(keys_sorted)}
        rgb_map = {remap[k]: v for k, v in rgb_map.items()}
        depth_map = {remap[k]: v for k, v in depth_map.items()}
        lo, hi = 0, len(keys_sorted) - 1
    n = hi + 1
    frames: list[FrameInfo] = []
    fps = camera.fps
    for i in range(n):
        f = FrameInfo(index=i, timestamp_s=i / fps, rgb_source=rgb_map.get(i), depth_source=depth_map.get(i))
        if f.rgb_source is None:
            if video is not None and video_note:
                f.flag("unreadable_rgb", f"frame {i}: {video_note}")
            elif video is not None:
                f.flag("missing_rgb", f"{video.name} has only {len(rgb_map)} frames (depth has {len(depth_map)})")
            else:
                f.flag("missing_rgb", f"no rgb/ image for frame {i}")
        if f.depth_source is None:
            f.flag("missing_depth", f"no depth/ file for frame {i}" if depth_map else "take has no depth/ folder")
        else:
            _check_depth_header(f, camera)
        frames.append(f)
    if video is None and rgb_files:
        for f in frames:
            if f.rgb_source is not None and os.path.getsize(f.rgb_source) == 0:
                f.flag("unreadable_rgb", f"{Path(f.rgb_source).name} is empty (0 bytes)")

    annotations = None
    ann_path = root / "annotations.json"
    if ann_path.is_file():
        annotations = parse_annotations(_load_json(ann_path, "annotations.json"), ann_path, n_frames=n)
    meta = {}
    if (root / "take.json").is_file():
        try:
            meta = json.loads((root / "take.json").read_text())
        except (OSError, json.JSONDecodeError):
            meta = {}
    return Take(path=root, camera=camera, frames=frames, annotations=annotations,
                rgb_kind="video" if video is not None else "images", video_path=video, meta=meta,
                video_decode_path=decode_path, notes=notes)


def _check_depth_header(f: FrameInfo, camera: CameraInfo) -> None:
    """Cheap checks of a depth file from its header: empty, unreadable header, wrong size."""
    p = Path(f.depth_source)
    want = (camera.height, camera.width)
    try:
        if p.stat().st_size == 0:
            f.flag("unreadable_depth", f"{p.name} is empty (0 bytes)")
            return
        if p.suffix.lower() == ".npy":
            hdr = _npy_header(p)
            if hdr is None:
                f.flag("unreadable_depth", f"{p.name}: not a valid .npy file")
                return
            shape = tuple(hdr[0])
            if len(shape) == 3 and shape[2] == 1:
                shape = shape[:2]
        else:
            s = _png_size(p)
            if s is None:
                f.flag("unreadable_depth", f"{p.name}: not a valid PNG file")
                return
            shape = (s[1], s[0])
    except OSError as e:
        f.flag("unreadable_depth", f"{p.name}: {e}")
        return
    if shape != want:
        f.flag("depth_size_mismatch", f"{p.name} has shape {shape}, camera.json says (height, width) = {want}")


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


def iter_depth(take: Take, batch_size: int = 32, *, num_workers: int = 2
               ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Depth only, every frame in order: yields (indices (B,), depth float32 (B, H, W) m, invalid = 0).

    Frames without usable depth come as all-zero (and are flagged on ``take.frames``), so the
    batches cover the whole take whatever the state of its RGB.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    idx = np.arange(take.n_frames)

    def load(i: int) -> np.ndarray:
        return _decode_depth(take.frames[int(i)], take.camera)

    with ThreadPoolExecutor(max_workers=max(1, num_workers)) as pool:
        for start in range(0, len(idx), batch_size):
            chunk = idx[start:start + batch_size]
            yield chunk, np.stack(list(pool.map(load, chunk)))


def read_frame(take: Take, index: int) -> tuple[np.ndarray | None, np.ndarray]:
    """One frame: (rgb uint8 (H, W, 3) or None if unusable, depth float32 metres, invalid = 0)."""
    for b in iter_frames(take, batch_size=1, frames=[index], num_workers=1):
        return b.rgb[0], b.depth[0]
    return None, _decode_depth(take.frames[index], take.camera)
