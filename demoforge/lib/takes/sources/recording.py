"""What every recording source (RealSense, Record3D, ROS 2 bags) shares: the side folder, the frame
index built once and remembered, frames placed on the time axis by their timestamps, streamed decoding.

A recording is never written to. What demoforge adds to it lives in its side folder
``<recording>.demoforge/`` (beside the file or folder): ``camera.json`` (the pose ``T_world_camera`` and
how it was found, written by ``demoforge calibrate``), ``annotations.json`` (``demoforge annotate``),
``source.json`` (the topics chosen with ``--rgb-topic`` ...), and for a recording made from a synthetic
take ``take.json`` and ``ground_truth/``.

The frame index (intrinsics, each frame's timestamp, locator and problems) takes one pass over the
recording; it is remembered under the digest cache (demoforge.lib.settings.digest_cache_dir), keyed
by the recording's identity (path, size, modification and change times) and the source's version, so
each later command opens a multi-GB recording without reading it.
"""

from __future__ import annotations

import abc
import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from demoforge.lib.settings import digest_cache_dir
from demoforge.lib.takes.metadata import load_json, parse_annotations, parse_pose
from demoforge.lib.takes.sources.base import TakeDecoder, TakeSource
from demoforge.lib.takes.types import DEFAULT_DEPTH_SCALE, CameraInfo, FrameInfo, Take, TakeError

SIDECAR_SUFFIX = ".demoforge"
#: a frame whose timestamp is more than this many frame periods after the previous one leaves a gap
GAP_FACTOR = 1.5


def sidecar_dir(path: str | os.PathLike) -> Path:
    """The side folder where demoforge keeps what it adds to a recording (``<recording>.demoforge``)."""
    p = Path(path).resolve()
    return p.parent / (p.name + SIDECAR_SUFFIX)


@dataclass
class RecordingIndex:
    """A recording's frames, found in one pass (JSON-able: remembered between commands)."""

    width: int
    height: int
    K: list                          # 3x3, for the RGB image at width x height
    fps: float
    timestamps_s: list[float]        # per frame index, seconds from the first frame
    keys: list[Any]                  # the source's locator per frame (None: no frame there)
    status: list[str]
    message: list[str]
    notes: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)   # source details: topics, device, depth scale, pairing, ...

    @property
    def n_frames(self) -> int:
        return len(self.keys)


def place_on_time_axis(times_s: np.ndarray, keys: list[Any], fps: float | None, what: str
                       ) -> tuple[float, list[float], list[Any], list[str], list[str]]:
    """Frames in timestamp order placed at index round((t - t0) * fps): a gap leaves ``dropped_frame``
    slots (the time axis stays uniform, as the pipeline assumes), a second frame on one slot is a
    ``repeated_frame`` (the copy is discarded). ``fps`` None: 1 / the median interval.

    Returns (fps, timestamps per index, keys per index, status, message)."""
    times_s = np.asarray(times_s, float)
    if times_s.size == 0:
        raise TakeError(f"{what}: no colour frames in the recording")
    order = np.argsort(times_s, kind="stable")
    t = times_s[order]
    if fps is None or not (fps > 0):
        dt = np.diff(t)
        dt = dt[dt > 0]
        fps = float(1.0 / np.median(dt)) if dt.size else 30.0
    slot = np.rint((t - t[0]) * fps).astype(np.int64)
    n = int(slot[-1]) + 1
    out_keys: list[Any] = [None] * n
    status, message = ["dropped_frame"] * n, [""] * n
    stamps = [i / fps for i in range(n)]
    for j, s in zip(order, slot):
        if out_keys[s] is None:
            out_keys[s] = keys[j]
            status[s] = "ok"
            stamps[s] = float(times_s[j] - t[0])
        else:
            status[s] = "repeated_frame"
            message[s] = f"frame delivered twice (timestamp {times_s[j] - t[0]:.4f} s); the copy is discarded"
    prev = 0
    for i in range(n):
        if out_keys[i] is not None:
            prev = i
        elif status[i] == "dropped_frame":
            message[i] = (f"dropped by the camera: no colour frame between {stamps[prev]:.3f} s and the next "
                          f"one (expected every {1000 / fps:.1f} ms)")
    return float(fps), stamps, out_keys, status, message


class Recording(abc.ABC):
    """Decodes one recording (a file or a folder). Subclasses build the index and stream frames."""

    #: bump when the index a subclass builds changes (cached indexes of another version are rebuilt)
    version = "1"

    def __init__(self, path: Path, options: dict | None = None):
        self.path = path
        self.options = dict(options or {})

    @abc.abstractmethod
    def build_index(self) -> RecordingIndex:
        """One pass over the recording; raises :class:`TakeError` for a recording that cannot be read."""

    @abc.abstractmethod
    def decode(self, index: RecordingIndex, wanted: list[int]
               ) -> Iterator[tuple[int, np.ndarray | None, np.ndarray | None, str]]:
        """Stream the ``wanted`` frames (increasing): (index, RGB uint8 (H, W, 3) or None, depth float32
        metres (H, W) registered to the RGB or None, what went wrong when either is None)."""

    def close(self) -> None:
        """Release what the decoder holds open."""


def _identity(path: Path) -> list:
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    out = []
    for f in files:
        st = f.stat()
        out.append([str(f.relative_to(path)) if f != path else f.name, st.st_size, st.st_mtime_ns, st.st_ctime_ns])
    return out


def cached_index(recording: Recording, progress: Any = None) -> RecordingIndex:
    """The recording's index, from the digest cache when the recording is unchanged, else built now."""
    path = recording.path.resolve()
    key = {"path": str(path), "identity": _identity(path), "source": type(recording).__name__,
           "version": recording.version, "options": {k: recording.options[k] for k in sorted(recording.options)}}
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]
    record = digest_cache_dir() / "recordings" / f"{digest}.json"
    try:
        return RecordingIndex(**json.loads(record.read_text()))
    except (OSError, ValueError, TypeError):
        pass
    index = recording.build_index()
    try:  # atomic; a failure only costs indexing again next time
        record.parent.mkdir(parents=True, exist_ok=True)
        tmp = record.with_name(f"{record.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(asdict(index)))
        os.replace(tmp, record)
    except OSError:
        pass
    return index


def read_sidecar_options(path: Path) -> dict:
    """The options remembered for a recording (``source.json`` in its side folder)."""
    f = sidecar_dir(path) / "source.json"
    if not f.is_file():
        return {}
    obj = load_json(f, "source.json")
    if not isinstance(obj, dict):
        raise TakeError(f"{f}: must be a JSON object of source options (e.g. {{\"rgb_topic\": ...}})")
    return obj


def remember_options(path: str | os.PathLike, **options: Any) -> None:
    """Keep the options given (not None) in the side folder's ``source.json``, so every later command
    opens the recording the same way."""
    given = {k: v for k, v in options.items() if v is not None}
    if not given:
        return
    side = sidecar_dir(path)
    merged = read_sidecar_options(Path(path)) | given
    side.mkdir(parents=True, exist_ok=True)
    tmp = side / f".source.json.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(merged, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, side / "source.json")


class RecordingSource(TakeSource):
    """A take source whose frames are decoded from a recording by :attr:`recording_cls`."""

    recording_cls: type[Recording]

    @classmethod
    def cache_key_inputs(cls, path: Path) -> dict[str, Path]:
        """The side folder (pose, annotations, options), when there is one."""
        side = sidecar_dir(path)
        return {"sidecar": side} if side.is_dir() else {}

    def open(self, path: Path, *, require_pose: bool = True, prefer: str = "images", cache_dir: Any = None,
             **options: Any) -> Take:
        """(``prefer`` and ``cache_dir`` are a take folder's: a recording has one colour stream and is read
        where it is.)"""
        path = Path(path).resolve()
        opts = read_sidecar_options(path) | {k: v for k, v in options.items() if v is not None}
        recording = self.recording_cls(path, opts)
        index = cached_index(recording)
        side = sidecar_dir(path)
        pose, method, cam_obj = None, None, {}
        cam_path = side / "camera.json"
        if cam_path.is_file():
            cam_obj = load_json(cam_path, "camera.json")
            if not isinstance(cam_obj, dict):
                raise TakeError(f"{cam_path}: must be a JSON object with T_world_camera (4x4)")
            pose = parse_pose(cam_obj, cam_path, require=False)
            method = str(cam_obj.get("pose_method") or "camera.json") if pose is not None else None
        if pose is None and require_pose:
            raise TakeError(f"{path}: the camera's pose in the table frame (T_world_camera) is not known yet; run "
                            f"`demoforge calibrate {path}` (a printed board on the table, or the table plane), or "
                            f"write it to {cam_path}")
        camera = CameraInfo(K=np.asarray(index.K, float), width=int(index.width), height=int(index.height),
                            T_world_camera=pose, fps=float(index.fps), depth_scale=DEFAULT_DEPTH_SCALE)
        frames = [FrameInfo(index=i, timestamp_s=float(index.timestamps_s[i]),
                            rgb_source=None if k is None else f"{path.name}#{i}",
                            depth_source=None if k is None else f"{path.name}#{i}",
                            status=s, message=m)
                  for i, (k, s, m) in enumerate(zip(index.keys, index.status, index.message))]
        annotations = None
        if (side / "annotations.json").is_file():
            annotations = parse_annotations(load_json(side / "annotations.json", "annotations.json"),
                                            side / "annotations.json", n_frames=len(frames))
        meta = {}
        if (side / "take.json").is_file():
            meta = load_json(side / "take.json", "take.json")
        return Take(path=path, camera=camera, frames=frames, annotations=annotations, rgb_kind="recording",
                    meta=meta if isinstance(meta, dict) else {}, notes=list(index.notes), source=self.name,
                    meta_dir=side, pose_method=method, decoder=RecordingDecoder(recording, index))


@dataclass
class RecordingDecoder(TakeDecoder):
    """What a recording take decodes with (Take.decoder): its :class:`Recording` streams RGB-D pairs."""

    recording: Recording
    index: RecordingIndex

    checks_depth_with_rgb = True

    def frames(self, wanted: list[int]) -> Iterator[tuple[int, np.ndarray | None, np.ndarray | None, str]]:
        wanted = [i for i in wanted if self.index.keys[i] is not None]
        if wanted:
            yield from self.recording.decode(self.index, wanted)

    @property
    def info(self) -> dict:
        return self.index.info

    def rgbd(self, take: Take, idx: list[int], batch_size: int, num_workers: int
             ) -> Iterator[list[tuple[int, np.ndarray, np.ndarray]]]:
        """The decoded frames in groups of ``batch_size``; a frame without usable RGB is flagged and skipped."""
        group: list = []
        for i, rgb, depth, msg in self.frames(idx):
            f = take.frames[i]
            if rgb is None:
                f.flag("unreadable_rgb", msg or f"frame {i}: colour frame cannot be decoded")
                continue
            group.append((i, rgb, _checked_depth(f, depth, take.camera, msg)))
            if len(group) == batch_size:
                yield group
                group = []
        if group:
            yield group

    def depth(self, take: Take, batch_size: int, num_workers: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        cam = take.camera
        zeros = np.zeros((cam.height, cam.width), np.float32)
        decoded = iter(self.frames(list(range(take.n_frames))))
        pending = next(decoded, None)
        for start in range(0, take.n_frames, batch_size):
            chunk = np.arange(start, min(start + batch_size, take.n_frames))
            out = []
            for i in chunk:
                f = take.frames[int(i)]
                if pending is not None and pending[0] == i:
                    out.append(_checked_depth(f, pending[2], cam, pending[3]))
                    pending = next(decoded, None)
                else:
                    out.append(zeros)
                    if f.status == "ok":
                        f.flag("missing_depth", f"frame {i}: no depth frame")
            yield chunk, np.stack(out)

    def lone_depth(self, take: Take, index: int) -> np.ndarray:
        return np.zeros((take.camera.height, take.camera.width), np.float32)


def _checked_depth(f: FrameInfo, depth: np.ndarray | None, camera: CameraInfo, msg: str) -> np.ndarray:
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


def scale_intrinsics(K: np.ndarray, from_size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """K for an image resized from (w, h) ``from_size`` to ``to_size`` (pixel-centre convention)."""
    sx, sy = to_size[0] / from_size[0], to_size[1] / from_size[1]
    K = np.asarray(K, float).copy()
    K[0, 0] *= sx
    K[0, 1] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return K


def finite_or(value: Any, default: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return v if math.isfinite(v) and v > 0 else default
