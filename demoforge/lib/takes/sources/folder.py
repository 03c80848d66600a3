"""The folder take sources: ``folder`` (rgb/ images + depth/ + camera.json) and ``mp4`` (the same folder
with its RGB as a video, ``rgb.mp4`` or its only ``*.mp4``; the video file itself may be given), and
their decoders: :class:`FolderDecoder` (images decoded in threads, depth files) and
:class:`VideoDecoder` (the video decoded in order, the same depth files).

Layout and per-frame policy: demoforge.lib.takes.reader's docstring (docs/takes.md).
"""

from __future__ import annotations

import json
import os
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.lib.takes.media import (
    find_video, image_header_size, list_files, npy_header, numbered_files, png_size, salvage_mp4, video_props,
)
from demoforge.lib.takes.metadata import load_json, parse_annotations, parse_camera
from demoforge.lib.takes.sources.base import TakeDecoder, TakeSource
from demoforge.lib.takes.types import DEPTH_EXTS, IMAGE_EXTS, CameraInfo, FrameInfo, Take, TakeError


class FolderSource(TakeSource):
    """A take folder with its RGB frames as images (``rgb/000000.png ...``)."""

    name = "folder"
    description = "take folder: rgb/ frames (PNG/JPG), depth/ (.npy metres or 16-bit PNG mm), camera.json"

    @classmethod
    def claims(cls, path: Path) -> bool:
        return path.is_dir() and (path / "camera.json").is_file() and bool(list_files(path / "rgb", IMAGE_EXTS))

    def open(self, path: Path, *, require_pose: bool = True, prefer: str = "images",
             cache_dir: str | os.PathLike | None = None, **options: Any) -> Take:
        """(A take folder has no source options: ``options`` are ignored.)"""
        return open_take_folder(path, prefer=prefer, cache_dir=cache_dir, require_pose=require_pose)


class Mp4Source(TakeSource):
    """A take folder whose RGB is a video (``rgb.mp4`` or the only ``*.mp4``), or that video file itself."""

    name = "mp4"
    description = "take folder with rgb.mp4 (or its .mp4 file), depth/, camera.json"

    @classmethod
    def claims(cls, path: Path) -> bool:
        if path.is_file():
            return path.suffix.lower() == ".mp4" and (path.parent / "camera.json").is_file()
        return path.is_dir() and (path / "camera.json").is_file()

    def open(self, path: Path, *, require_pose: bool = True, prefer: str = "video",
             cache_dir: str | os.PathLike | None = None, **options: Any) -> Take:
        if path.is_file():
            return open_take_folder(path.parent, prefer="video", cache_dir=cache_dir, require_pose=require_pose)
        return open_take_folder(path, prefer=prefer, cache_dir=cache_dir, require_pose=require_pose)


def open_take_folder(root: Path, *, prefer: str = "images", cache_dir: str | os.PathLike | None = None,
                     require_pose: bool = True) -> Take:
    """Open a take folder: validate camera.json / annotations.json and index the frames (see
    demoforge.lib.takes.reader.open_take)."""
    if not root.is_dir():
        raise TakeError(f"{root}: take folder does not exist (expected rgb/ or rgb.mp4, depth/, camera.json)")
    cam_path = root / "camera.json"
    if not cam_path.is_file():
        raise TakeError(f"{cam_path}: camera.json is missing; write it with K (3x3), width, height and "
                        f"T_world_camera (4x4 camera-to-world) (fps optional, default 30)")
    cam_obj = load_json(cam_path, "camera.json")
    camera = parse_camera(cam_obj, cam_path, require_pose=require_pose)
    if prefer not in ("images", "video"):
        raise ValueError(f"prefer must be 'images' or 'video', got {prefer!r}")
    rgb_files = sorted(list_files(root / "rgb", IMAGE_EXTS))
    video = None
    if not rgb_files or prefer == "video":
        try:
            video = find_video(root)
        except TakeError:
            if not rgb_files:
                raise
    if video is not None:
        rgb_files = []
    notes: list[str] = []
    decode_path, video_note, rgb_map = video, "", {}
    if video is not None:
        decode_path, video_note, rgb_map = _index_video(video, camera, cam_path, cache_dir)
        if video_note:
            notes.append(video_note)
    else:
        rgb_map = _index_images(root, rgb_files, camera, cam_path)
    depth_map = _index_depth(root, rgb_files if video is None else [])
    if not rgb_map and not depth_map:
        raise TakeError(f"{root}: no frames found: need rgb/ with .png/.jpg frames or an .mp4 video, and depth/"
                        + (f" ({video_note})" if video_note else ""))
    frames = _frame_list(rgb_map, depth_map, camera, video, video_note)
    if video is None and rgb_files:
        for f in frames:
            if f.rgb_source is not None and os.path.getsize(f.rgb_source) == 0:
                f.flag("unreadable_rgb", f"{Path(f.rgb_source).name} is empty (0 bytes)")
    annotations = None
    ann_path = root / "annotations.json"
    if ann_path.is_file():
        annotations = parse_annotations(load_json(ann_path, "annotations.json"), ann_path, n_frames=len(frames))
    meta = {}
    if (root / "take.json").is_file():
        try:
            meta = json.loads((root / "take.json").read_text())
        except (OSError, json.JSONDecodeError):
            meta = {}
    return Take(path=root, camera=camera, frames=frames, annotations=annotations,
                rgb_kind="video" if video is not None else "images", video_path=video, meta=meta,
                video_decode_path=decode_path, notes=notes, source="mp4" if video is not None else "folder",
                meta_dir=root, pose_method=(str(cam_obj.get("pose_method") or "camera.json")
                                            if camera.T_world_camera is not None else None),
                decoder=FolderDecoder() if video is None else VideoDecoder(video, decode_path or video))


def _index_video(video: Path, camera: CameraInfo, cam_path: Path, cache_dir) -> tuple[Path, str, dict[int, str]]:
    """(what to decode, a note when the video is damaged, {frame: "<video>#<n>"})."""
    props = video_props(video)
    decode_path, note = video, ""
    if props is None:
        where = Path(cache_dir) if cache_dir is not None else folder_removed_at_exit("demoforge_video_")
        salv = salvage_mp4(video, camera, where)
        if salv is not None:
            decode_path, n_ok = salv
            props = (n_ok, camera.width, camera.height)
            note = (f"{video.name} is truncated (its index is missing); {n_ok} complete frames "
                    f"recovered, the rest of the video is lost")
        else:
            if cache_dir is None:
                shutil.rmtree(where, ignore_errors=True)
            note = (f"{video.name} cannot be opened by OpenCV (truncated or corrupt file: its index "
                    f"may be missing); re-export the video or provide rgb/ frames")
    if props is None:
        return decode_path, note, {}
    n_video, vw, vh = props
    if (vw, vh) != (camera.width, camera.height) and vw > 0:
        raise TakeError(f"{cam_path}: width x height = {camera.width} x {camera.height} but {video.name} "
                        f"is {vw} x {vh}; fix camera.json (and K) to the video's size")
    return decode_path, note, {i: f"{video}#{i}" for i in range(n_video)}


def _index_images(root: Path, rgb_files: list[Path], camera: CameraInfo, cam_path: Path) -> dict[int, str]:
    numbered = numbered_files(rgb_files, "rgb", root / "rgb")
    if numbered is None:
        numbered = {i: p for i, p in enumerate(sorted(rgb_files, key=lambda p: p.name))}
    first = min(numbered) if numbered else 0
    if rgb_files:
        p0 = numbered[first]
        size = image_header_size(p0)
        if size is not None and size != (camera.width, camera.height):
            raise TakeError(f"{cam_path}: width x height = {camera.width} x {camera.height} but {p0.name} is "
                            f"{size[0]} x {size[1]}; fix camera.json (and K) to the frames' size")
    return {n - first: str(p) for n, p in numbered.items()}


def _index_depth(root: Path, rgb_files: list[Path]) -> dict[int, str]:
    depth_files = sorted(list_files(root / "depth", DEPTH_EXTS))
    depth_numbered = numbered_files(depth_files, "depth", root / "depth")
    if depth_numbered is None:
        return {i: str(p) for i, p in enumerate(sorted(depth_files, key=lambda p: p.name))}
    if rgb_files:
        first = min(n for n in (numbered_files(rgb_files, "rgb", root / "rgb") or {0: None}))
    else:
        first = min(depth_numbered) if depth_numbered else 0
    return {n - first: str(p) for n, p in depth_numbered.items()}


def _frame_list(rgb_map: dict[int, str], depth_map: dict[int, str], camera: CameraInfo, video: Path | None,
                video_note: str) -> list[FrameInfo]:
    keys = set(rgb_map) | set(depth_map)
    lo, hi = min(keys), max(keys)
    if lo < 0:
        remap = {k: i for i, k in enumerate(sorted(keys))}
        rgb_map = {remap[k]: v for k, v in rgb_map.items()}
        depth_map = {remap[k]: v for k, v in depth_map.items()}
        hi = len(keys) - 1
    frames: list[FrameInfo] = []
    for i in range(hi + 1):
        f = FrameInfo(index=i, timestamp_s=i / camera.fps, rgb_source=rgb_map.get(i), depth_source=depth_map.get(i))
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
            check_depth_header(f, camera)
        frames.append(f)
    return frames


def check_depth_header(f: FrameInfo, camera: CameraInfo) -> None:
    """Cheap checks of a depth file from its header: empty, unreadable header, wrong size."""
    p = Path(f.depth_source)
    want = (camera.height, camera.width)
    try:
        if p.stat().st_size == 0:
            f.flag("unreadable_depth", f"{p.name} is empty (0 bytes)")
            return
        if p.suffix.lower() == ".npy":
            hdr = npy_header(p)
            if hdr is None:
                f.flag("unreadable_depth", f"{p.name}: not a valid .npy file")
                return
            shape = tuple(hdr[0])
            if len(shape) == 3 and shape[2] == 1:
                shape = shape[:2]
        else:
            s = png_size(p)
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

class FolderDecoder(TakeDecoder):
    """A take folder's frames: RGB images (decoded in parallel threads) and depth files."""

    def rgbd(self, take: Take, idx: list[int], batch_size: int, num_workers: int
             ) -> Iterator[list[tuple[int, np.ndarray, np.ndarray]]]:
        """``batch_size`` frames at a time, each batch without the frames whose image cannot be decoded."""
        cam = take.camera

        def load(i: int):
            f = take.frames[i]
            rgb, msg = decode_rgb_image(f.rgb_source, cam)
            if rgb is None:
                f.flag("unreadable_rgb", msg)
                return None
            return i, rgb, decode_depth(f, cam)

        pool = ThreadPoolExecutor(max_workers=max(1, num_workers)) if num_workers > 1 else None
        try:
            for start in range(0, len(idx), batch_size):
                chunk = idx[start:start + batch_size]
                got = list(pool.map(load, chunk)) if pool is not None else [load(i) for i in chunk]
                got = [g for g in got if g is not None]
                if got:
                    yield got
        finally:
            if pool is not None:
                pool.shutdown(wait=True)

    def depth(self, take: Take, batch_size: int, num_workers: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        idx = np.arange(take.n_frames)

        def load(i: int) -> np.ndarray:
            return decode_depth(take.frames[int(i)], take.camera)

        with ThreadPoolExecutor(max_workers=max(1, num_workers)) as pool:
            for start in range(0, len(idx), batch_size):
                chunk = idx[start:start + batch_size]
                yield chunk, np.stack(list(pool.map(load, chunk)))

    def lone_depth(self, take: Take, index: int) -> np.ndarray:
        return decode_depth(take.frames[index], take.camera)


class VideoDecoder(FolderDecoder):
    """A take folder whose RGB is a video: decoded in order (``decode_path``: a truncated video's
    recovered stream, else the video itself); depth from depth/ as for images."""

    def __init__(self, video: Path, decode_path: Path):
        self.video = video
        self.decode_path = decode_path

    def rgbd(self, take: Take, idx: list[int], batch_size: int, num_workers: int
             ) -> Iterator[list[tuple[int, np.ndarray, np.ndarray]]]:
        cam = take.camera
        group: list = []
        for i, rgb in self._iter_video(set(idx)):
            f = take.frames[i]
            if rgb is None:
                f.flag("unreadable_rgb", f"frame {i} of {self.video.name} could not be decoded "
                                         f"(video truncated or corrupt)")
                continue
            if rgb.shape[:2] != (cam.height, cam.width):
                f.flag("unreadable_rgb", f"video frame {i} is {rgb.shape[1]} x {rgb.shape[0]}, camera.json "
                                         f"says {cam.width} x {cam.height}")
                continue
            group.append((i, rgb, decode_depth(f, cam)))
            if len(group) == batch_size:
                yield group
                group = []
        if group:
            yield group

    def _iter_video(self, wanted: set[int]) -> Iterator[tuple[int, np.ndarray | None]]:
        """Decode the video sequentially; yields (index, rgb or None) for wanted frames of the container."""
        import cv2

        cap = cv2.VideoCapture(str(self.decode_path))
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


def decode_rgb_image(path: str, camera: CameraInfo) -> tuple[np.ndarray | None, str]:
    """An RGB image file as uint8 RGB (16-bit: its high byte; grey and BGRA converted), or (None, what
    is wrong) when it cannot be decoded or is not camera.json's size."""
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


def decode_depth(f: FrameInfo, camera: CameraInfo) -> np.ndarray:
    """A frame's depth file in metres (float32, invalid = 0); flags the frame on any problem (all-invalid then)."""
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
