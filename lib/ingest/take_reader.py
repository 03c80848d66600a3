"""Read a take folder (real recording or synthetic take) without decoding all of it up front.

Take folder layout (the same for a real RGB-D recording and for :mod:`lib.synth.take`)::

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
import math
import os
import re
import struct
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, NamedTuple, Sequence

import numpy as np

from lib.errors import UserError

__all__ = [
    "FRAME_STATUSES",
    "TakeError",
    "CameraInfo",
    "FrameInfo",
    "Annotations",
    "Take",
    "FrameBatch",
    "ThesisHand",
    "open_take",
    "iter_frames",
    "read_frame",
    "parse_camera",
    "parse_annotations",
    "read_thesis_keypoints_json",
    "frame_number",
]

#: Every value :attr:`FrameInfo.status` can take.
FRAME_STATUSES = (
    "ok", "missing_depth", "missing_rgb", "unreadable_rgb", "unreadable_depth",
    "depth_size_mismatch", "all_zero_depth",
)
#: Statuses for which the frame has no usable RGB (skipped by :func:`iter_frames`).
RGB_BAD = ("missing_rgb", "unreadable_rgb")

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
    T_world_camera: np.ndarray    # (4, 4) float64, camera to world
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
    #: the optional "task" section (lib.annotate.TaskDefinition): task, keypoints per object, arms
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
    rgb_kind: str                 # "images" or "video"
    video_path: Path | None = None
    meta: dict = field(default_factory=dict)   # take.json when present (synthetic takes)
    #: what is actually decoded for a video take (a salvaged stream when the mp4 was truncated)
    video_decode_path: Path | None = None
    notes: list[str] = field(default_factory=list)  # take-level remarks (e.g. video salvaged)

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
        return str(self.meta.get("take_id") or self.meta.get("take") or self.path.name)

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
        return self.path / "ground_truth"

    @property
    def has_ground_truth(self) -> bool:
        return (self.ground_truth_dir / "gt_hand_joints.parquet").is_file()


class FrameBatch(NamedTuple):
    """A batch from :func:`iter_frames`; unpacks as ``indices, rgb, depth``."""

    indices: np.ndarray   # (B,) int64 frame indices
    rgb: np.ndarray       # (B, H, W, 3) uint8, RGB order
    depth: np.ndarray     # (B, H, W) float32 metres, invalid = 0


# ------------------------------------------------------------------------------------------------
# camera.json and annotations.json
# ------------------------------------------------------------------------------------------------

def _load_json(path: Path, what: str) -> Any:
    try:
        text = path.read_text()
    except OSError as e:
        raise TakeError(f"{path}: cannot read {what}: {e}") from e
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise TakeError(f"{path}: {what} is not valid JSON ({e}); fix the syntax of the file") from e


def _matrix(obj: dict, key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    if key not in obj:
        raise TakeError(f"{path}: key {key!r} is missing; add it as a {shape[0]}x{shape[1]} nested list "
                        f"(row-major)")
    try:
        m = np.asarray(obj[key], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TakeError(f"{path}: {key!r} must be a {shape[0]}x{shape[1]} nested list of numbers ({e})") from e
    if m.shape != shape:
        if m.size == shape[0] * shape[1] and m.ndim == 1:
            m = m.reshape(shape)
        else:
            raise TakeError(f"{path}: {key!r} must be {shape[0]}x{shape[1]}, got shape {m.shape}; "
                            f"write it as a nested list of {shape[0]} rows")
    if not np.all(np.isfinite(m)):
        raise TakeError(f"{path}: {key!r} contains NaN or infinite values")
    return m


def parse_camera(obj: Any, path: str | os.PathLike = "camera.json") -> CameraInfo:
    """Validate a camera.json object. Raises :class:`TakeError` naming the key and the fix."""
    path = Path(path)
    if not isinstance(obj, dict):
        raise TakeError(f"{path}: must be a JSON object with keys K, width, height, T_world_camera")
    K = _matrix(obj, "K", (3, 3), path)
    fx, fy = K[0, 0], K[1, 1]
    if fx <= 0 or fy <= 0:
        raise TakeError(f"{path}: K has non-positive focal length (fx={fx}, fy={fy}); K must be "
                        f"[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels with fx, fy > 0")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9) or abs(K[1, 0]) > 1e-9:
        raise TakeError(f"{path}: K's last row must be [0, 0, 1] and K[1][0] must be 0, got {K.tolist()}; "
                        f"K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (did you write it transposed?)")
    size = {}
    for key in ("width", "height"):
        if key not in obj:
            raise TakeError(f"{path}: key {key!r} is missing; add the image {key} in pixels")
        v = obj[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v <= 0:
            raise TakeError(f"{path}: {key!r} must be a positive integer (pixels), got {v!r}")
        size[key] = int(v)
    T = _matrix(obj, "T_world_camera", (4, 4), path)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise TakeError(f"{path}: T_world_camera's last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    ortho = np.abs(R.T @ R - np.eye(3)).max()
    det = np.linalg.det(R)
    if ortho > 1e-3 or abs(det - 1.0) > 1e-3:
        raise TakeError(
            f"{path}: T_world_camera is not a rigid transform (rotation part: max |R^T R - I| = {ortho:.3g}, "
            f"det = {det:.4g}; need an orthonormal R with det +1). It must be the 4x4 camera-to-world "
            f"pose in metres, OpenCV camera axes; no scale or reflection")
    fps = obj.get("fps", DEFAULT_FPS)
    if fps is None:
        fps = DEFAULT_FPS
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps) or fps <= 0:
        raise TakeError(f"{path}: 'fps' must be a positive number (frames per second), got {fps!r}")
    scale = obj.get("depth_scale")
    unit = obj.get("depth_unit")
    if scale is None:
        scale = {"mm": 0.001, "m": DEFAULT_DEPTH_SCALE, None: DEFAULT_DEPTH_SCALE}.get(unit)
        if scale is None:
            raise TakeError(f"{path}: 'depth_unit' must be 'm' or 'mm', got {unit!r}")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (scale > 0) or not math.isfinite(scale):
        raise TakeError(f"{path}: 'depth_scale' must be a positive number (metres per depth unit), got {scale!r}")
    return CameraInfo(K=K, width=size["width"], height=size["height"], T_world_camera=T,
                      fps=float(fps), depth_scale=float(scale))


def _int_pair_list(v: Any, where: str, path: Path) -> list[tuple[int, int]]:
    if not isinstance(v, list):
        raise TakeError(f"{path}: {where} must be a list of [start, end) frame ranges, got {type(v).__name__}")
    out = []
    for i, r in enumerate(v):
        if (not isinstance(r, (list, tuple)) or len(r) != 2
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) or x != int(x) for x in r)):
            raise TakeError(f"{path}: {where}[{i}] must be [start, end] with integer frame indices, got {r!r}")
        s, e = int(r[0]), int(r[1])
        if s < 0 or e <= s:
            raise TakeError(f"{path}: {where}[{i}] = {r!r}: need 0 <= start < end "
                            f"([start, end), end exclusive, 0-based)")
        out.append((s, e))
    out.sort()
    for (s0, e0), (s1, e1) in zip(out, out[1:]):
        if s1 < e0:
            raise TakeError(f"{path}: {where} has overlapping ranges [{s0}, {e0}) and [{s1}, {e1}); merge them")
    return out


def parse_annotations(obj: Any, path: str | os.PathLike = "annotations.json",
                      n_frames: int | None = None) -> Annotations:
    """Validate annotations.json (format: lib/synth/take.py's docstring). Both sections are optional.

    ``object_keypoints_2d``: ``{"frame": int, "names": [str] * k, "uv": [[u, v]] * k}``;
    ``gripper_closed_ranges``: ``{"left": [[start, end], ...], "right": [...]}``, [start, end) 0-based.
    Raises :class:`TakeError` naming the problem.
    """
    path = Path(path)
    if not isinstance(obj, dict):
        raise TakeError(f"{path}: must be a JSON object with 'object_keypoints_2d' and/or 'gripper_closed_ranges'")
    frame, names, uv = None, (), np.zeros((0, 2))
    okp = obj.get("object_keypoints_2d")
    if okp is not None:
        if not isinstance(okp, dict):
            raise TakeError(f"{path}: 'object_keypoints_2d' must be an object {{frame, names, uv}}")
        for key in ("frame", "names", "uv"):
            if key not in okp:
                raise TakeError(f"{path}: 'object_keypoints_2d' lacks key {key!r}")
        frame = okp["frame"]
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
            raise TakeError(f"{path}: object_keypoints_2d.frame must be a 0-based frame index, got {frame!r}")
        if n_frames is not None and frame >= n_frames:
            raise TakeError(f"{path}: object_keypoints_2d.frame = {frame} but the take has {n_frames} frames")
        names = okp["names"]
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise TakeError(f"{path}: object_keypoints_2d.names must be a list of strings")
        if len(set(names)) != len(names):
            raise TakeError(f"{path}: object_keypoints_2d.names has duplicates")
        try:
            uv = np.asarray(okp["uv"], dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise TakeError(f"{path}: object_keypoints_2d.uv must be a list of [u, v] numbers ({e})") from e
        if uv.size == 0:
            uv = uv.reshape(0, 2)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise TakeError(f"{path}: object_keypoints_2d.uv must be a list of [u, v] pairs, got shape {uv.shape}")
        if uv.shape[0] != len(names):
            raise TakeError(f"{path}: object_keypoints_2d has {len(names)} names but {uv.shape[0]} uv points; "
                            f"they must match one to one")
        if not np.all(np.isfinite(uv)):
            raise TakeError(f"{path}: object_keypoints_2d.uv contains NaN or infinite values")
        names = tuple(names)
    ranges: dict[str, list[tuple[int, int]]] = {}
    gcr = obj.get("gripper_closed_ranges")
    if gcr is not None:
        if not isinstance(gcr, dict):
            raise TakeError(f"{path}: 'gripper_closed_ranges' must be an object {{\"left\": [...], \"right\": [...]}}")
        extra = set(gcr) - {"left", "right"}
        if extra:
            raise TakeError(f"{path}: gripper_closed_ranges has unknown key(s) {sorted(extra)}; use 'left' and 'right'")
        for side in ("left", "right"):
            ranges[side] = _int_pair_list(gcr.get(side, []), f"gripper_closed_ranges.{side}", path)
            if n_frames is not None and ranges[side] and ranges[side][-1][1] > n_frames:
                raise TakeError(f"{path}: gripper_closed_ranges.{side} ends at frame {ranges[side][-1][1]} "
                                f"but the take has {n_frames} frames")
    task = None
    if obj.get("task") is not None:
        from lib.annotate.model import parse_task_section  # lazy: lib.annotate builds on this module

        task = parse_task_section(obj["task"], str(path))
        unknown = [n for n in names if n not in task.keypoint_names]
        if unknown:
            raise TakeError(f"{path}: object_keypoints_2d.names {unknown} are not keypoints of the file's task "
                            f"{task.name!r} ({list(task.keypoint_names)})")
    if okp is None and gcr is None and task is None:
        raise TakeError(f"{path}: has neither 'object_keypoints_2d' nor 'gripper_closed_ranges'")
    return Annotations(object_keypoints_frame=frame, object_keypoint_names=names,
                       object_keypoints_uv=uv, gripper_closed_ranges=ranges, raw=obj, task=task)


# ------------------------------------------------------------------------------------------------
# frame indexing
# ------------------------------------------------------------------------------------------------

_NUM = re.compile(r"(\d+)")


def frame_number(name: str) -> int | None:
    """The last run of digits in a file name's stem (``rgb_frame000363.png`` -> 363), or None."""
    nums = _NUM.findall(Path(name).stem)
    return int(nums[-1]) if nums else None


def _list_files(folder: Path, exts: Sequence[str]) -> list[Path]:
    if not folder.is_dir():
        return []
    return [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in exts and not p.name.startswith(".")]


def _numbered(files: list[Path], what: str, folder: Path) -> dict[int, Path] | None:
    """Map frame number -> file; None when some name has no number (pair by position instead)."""
    nums = [frame_number(p.name) for p in files]
    if any(n is None for n in nums):
        return None
    out: dict[int, Path] = {}
    for n, p in zip(nums, files):
        if n in out:
            raise TakeError(f"{folder}: {out[n].name} and {p.name} have the same frame number {n}; "
                            f"keep one file per frame in {what}/")
        out[n] = p
    return out


def _png_size(path: Path) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) from a PNG's IHDR, or None if not a PNG."""
    with open(path, "rb") as f:
        head = f.read(29)
    if len(head) < 29 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    w, h = struct.unpack(">II", head[16:24])
    return w, h, head[24], head[25]


def _jpg_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a JPEG's SOF marker, or None if it cannot be found."""
    with open(path, "rb") as f:
        data = f.read(1 << 20)
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            i += 1
            continue
        marker = data[i + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
            i += 1 if marker == 0xFF else 2
            continue
        seg = struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return w, h
        i += 2 + seg
    return None


def _image_header_size(path: Path) -> tuple[int, int] | None:
    s = _png_size(path)
    if s is not None:
        return s[0], s[1]
    return _jpg_size(path)


def _npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype] | None:
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, _, dtype = np.lib.format.read_array_header_2_0(f)
        return shape, dtype
    except Exception:  # noqa: BLE001 - any header problem = unreadable
        return None


def _find_video(root: Path) -> Path | None:
    v = root / "rgb.mp4"
    if v.is_file():
        return v
    vids = sorted(p for p in root.glob("*.mp4") if p.is_file())
    if len(vids) == 1:
        return vids[0]
    if len(vids) > 1:
        raise TakeError(f"{root}: several .mp4 files ({', '.join(p.name for p in vids)}) and no rgb/ folder; "
                        f"name the take's video rgb.mp4 or keep only one")
    return None


def _mp4_boxes(data: bytes) -> Iterator[tuple[bytes, int, int, int]]:
    """Top-level ISO-BMFF boxes: (type, offset, header size, declared size)."""
    i = 0
    while i + 8 <= len(data):
        size, typ = struct.unpack(">I4s", data[i:i + 8])
        hdr = 8
        if size == 1:
            if i + 16 > len(data):
                return
            size = struct.unpack(">Q", data[i + 8:i + 16])[0]
            hdr = 16
        elif size == 0:
            size = len(data) - i
        if size < hdr:
            return
        yield typ, i, hdr, size
        i += size


_VOP = b"\x00\x00\x01\xb6"      # MPEG-4 Part 2 video object plane start code
_VOL = b"\x00\x00\x01\xb0"      # visual object sequence start code


def _reference_mp4v_header(width: int, height: int, fps: float) -> bytes | None:
    """The MPEG-4 Part 2 decoder config (VOS/VOL header) OpenCV's mp4v writer uses at this size."""
    import tempfile

    import cv2

    with tempfile.TemporaryDirectory() as d:
        ref = os.path.join(d, "ref.mp4")
        w = cv2.VideoWriter(ref, cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (int(width), int(height)))
        if not w.isOpened():
            return None
        w.write(np.zeros((int(height), int(width), 3), np.uint8))
        w.release()
        r = Path(ref).read_bytes()
    k = r.find(_VOL)
    if k < 0:
        return None
    j = k - 1
    while j > 0 and r[j] != 0x05:      # DecoderSpecificInfo descriptor tag, then its length
        j -= 1
    p, ln = j + 1, 0
    while p < k:
        c = r[p]
        ln = (ln << 7) | (c & 0x7F)
        p += 1
        if not c & 0x80:
            break
    return r[k:k + ln] if p == k and ln > 0 else None


def _salvage_mp4(path: Path, camera: CameraInfo, out_dir: Path) -> tuple[Path, int] | None:
    """Recover the complete frames of an mp4 whose index (moov box, written last) was cut off.

    Works for MPEG-4 Part 2 video (OpenCV's ``mp4v`` writer, used by lib.synth.take): the complete
    frames of the ``mdat`` payload are written as an elementary stream after the decoder header that
    OpenCV's writer produces at the same size. Returns (stream path, number of complete frames), or
    None when the file is not such a video.
    """
    try:
        data = path.read_bytes()
    except OSError:
        return None
    mdat = [(i, hdr, size) for typ, i, hdr, size in _mp4_boxes(data) if typ == b"mdat"]
    if not mdat or any(typ == b"moov" for typ, *_ in _mp4_boxes(data)):
        return None
    i, hdr, size = mdat[0]
    payload = data[i + hdr:i + size]
    starts = [m.start() for m in re.finditer(re.escape(_VOP), payload)]
    if not starts:
        return None
    if i + size > len(data):           # the last frame was cut mid-way: keep complete frames only
        payload = payload[:starts[-1]]
        starts = starts[:-1]
    if not starts:
        return None
    head = b"" if payload.find(_VOL, 0, starts[0]) >= 0 else _reference_mp4v_header(
        camera.width, camera.height, camera.fps)
    if head is None:
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / (path.stem + ".salvaged.m4v")
    out.write_bytes(head + payload)
    return out, len(starts)


def _video_props(path: Path) -> tuple[int, int, int] | None:
    """(frame count from the container, width, height), or None if OpenCV cannot open it."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            return None
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        return max(n, 0), w, h
    finally:
        cap.release()


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
            import tempfile

            where = Path(cache_dir) if cache_dir is not None else Path(tempfile.mkdtemp(prefix="demoforge_video_"))
            salv = _salvage_mp4(video, camera, where)
            if salv is not None:
                decode_path, n_ok = salv
                props = (n_ok, camera.width, camera.height)
                video_note = (f"{video.name} is truncated (its index is missing); {n_ok} complete frames "
                              f"recovered, the rest of the video is lost")
                notes.append(video_note)
            else:
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


# ------------------------------------------------------------------------------------------------
# the thesis code's keypoint JSON
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ThesisHand:
    """One hand of one image in the thesis code's keypoint JSON."""

    image: str                   # the JSON key (image file name)
    frame: int                   # frame index (see read_thesis_keypoints_json)
    hand: str                    # "left" | "right"
    joints_rel: np.ndarray       # (21, 3) "3d_keypoints" (HaMeR pred_keypoints_3d, left already un-mirrored)
    translation: np.ndarray      # (3,) "translation" (HaMeR pred_cam_t_full)
    joints_cam: np.ndarray       # (21, 3) joints_rel + translation: camera frame, m
    joints_px: np.ndarray | None  # (21, 2) "2d_keypoints" when present
    focal_length: float | None   # "focal_length" the file's 2D keypoints were projected with
    confidence: float | None     # "confidence" when present (the thesis code writes none)


def read_thesis_keypoints_json(path: str | os.PathLike, *, take: Take | None = None,
                               frame_names: Sequence[str] | None = None) -> list[ThesisHand]:
    """Read the keypoint JSON written by the thesis's code (Jiayun-Zhang/Hand_keypoint_detector, run.py).

    Format (checked against that repository's ``run.py``)::

        {"<image file name>": {"left":  {"3d_keypoints": 21x3, "translation": [3],
                                         "2d_keypoints": 21x2, "focal_length": f} | {} | null,
                               "right": {...} | {} | null}, ...}

    An absent hand is ``{}`` (what run.py writes) or ``null``; images without any hand are not in the
    file. run.py stores HaMeR's relative ``pred_keypoints_3d`` (x mirrored back for the left hand) and
    ``pred_cam_t_full`` as ``translation``; the camera-frame joints are ``3d_keypoints + translation``.
    Its ``2d_keypoints`` were projected with K = [[f, 0, 320], [0, f, 240], [0, 0, 1]] (f =
    ``focal_length``, 525 in run.py).

    Frame index of a key: its position in ``frame_names`` (or in the take's rgb file names) when it is
    there, else the number in the name minus the smallest number in the file.

    Raises:
        TakeError: unreadable JSON or a malformed entry (naming the image and hand).
    """
    p = Path(path)
    obj = _load_json(p, "keypoint JSON")
    if not isinstance(obj, dict):
        raise TakeError(f"{p}: must map image file names to {{'left': ..., 'right': ...}}")
    names = list(frame_names) if frame_names is not None else None
    if names is None and take is not None and take.rgb_kind == "images":
        names = [Path(f.rgb_source).name if f.rgb_source else "" for f in take.frames]
    by_name = {n: i for i, n in enumerate(names)} if names else {}
    nums = [frame_number(k) for k in obj]
    first = min((n for n in nums if n is not None), default=0)
    out: list[ThesisHand] = []
    for key, entry in obj.items():
        base = Path(key).name
        if base in by_name:
            frame = by_name[base]
        else:
            num = frame_number(base)
            if num is None:
                raise TakeError(f"{p}: key {key!r} has no frame number and is not one of the take's frame names")
            frame = num - first
        if not isinstance(entry, dict):
            raise TakeError(f"{p}: entry {key!r} must be an object with 'left' and 'right'")
        for side in ("left", "right"):
            h = entry.get(side)
            if not h:
                continue
            if not isinstance(h, dict) or "3d_keypoints" not in h or "translation" not in h:
                raise TakeError(f"{p}: {key!r}.{side} must have '3d_keypoints' (21x3) and 'translation' (3)")
            try:
                rel = np.asarray(h["3d_keypoints"], float)
                t = np.asarray(h["translation"], float).reshape(-1)
                px = np.asarray(h["2d_keypoints"], float) if h.get("2d_keypoints") is not None else None
            except (TypeError, ValueError) as e:
                raise TakeError(f"{p}: {key!r}.{side}: non-numeric keypoints ({e})") from e
            if rel.shape != (21, 3) or t.shape != (3,):
                raise TakeError(f"{p}: {key!r}.{side}: 3d_keypoints must be 21x3 and translation 3 values, "
                                f"got {rel.shape} and {t.shape}")
            if px is not None and px.shape != (21, 2):
                raise TakeError(f"{p}: {key!r}.{side}: 2d_keypoints must be 21x2, got {px.shape}")
            conf = h.get("confidence")
            fl = h.get("focal_length")
            out.append(ThesisHand(image=key, frame=int(frame), hand=side, joints_rel=rel, translation=t,
                                  joints_cam=rel + t, joints_px=px,
                                  focal_length=float(fl) if fl is not None else None,
                                  confidence=float(conf) if conf is not None else None))
    out.sort(key=lambda h: (h.frame, h.hand))
    return out
