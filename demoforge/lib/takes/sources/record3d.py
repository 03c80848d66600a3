"""Record3D (iPhone/iPad LiDAR) recordings: the ``.r3d`` file (a zip) and the exported folder.

Layout (both)::

    metadata            JSON: w, h (RGB size), K (9 numbers, column-major, for w x h), fps, poses
                        (per frame qx, qy, qz, qw, px, py, pz: the camera in ARKit's world, metres),
                        optionally dw, dh (depth size) and frameTimestamps (s)
    rgbd/N.jpg          the colour frame N
    rgbd/N.depth        LZFSE-compressed float32 depth in metres, at a lower resolution than the RGB
                        (256 x 192 for 960 x 720): its size is dw x dh, else inferred from its length
                        and the RGB's aspect ratio
    rgbd/N.conf         LZFSE-compressed uint8 confidence of the same size (0 low, 1 medium, 2 high)

Depth is resized to the RGB image with nearest neighbours (no depth is invented between two surfaces),
pixels with confidence below ``min_confidence`` (default 1: low is invalid) become 0, and K is scaled
to the RGB image actually stored. Record3D's camera poses are checked: a camera that moved more than
1 cm from its first pose is reported per frame (``camera_moved``) and in the take's notes, since the
pipeline assumes a static camera.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from demoforge.lib.takes.media import frame_number
from demoforge.lib.takes.sources.recording import (
    Recording, RecordingIndex, RecordingSource, finite_or, place_on_time_axis, scale_intrinsics,
)
from demoforge.lib.takes.types import TakeError

#: camera motion (m) from the first pose above which a frame is flagged ``camera_moved``
MOVED_M = 0.01


class Record3DRecording(Recording):
    version = "1"

    def __init__(self, path: Path, options: dict | None = None):
        super().__init__(path, options)
        self._zip: zipfile.ZipFile | None = None

    # -- members, in the zip or the folder ----------------------------------------------------------
    def _names(self) -> list[str]:
        if self.path.is_dir():
            return [str(p.relative_to(self.path)) for p in self.path.rglob("*") if p.is_file()]
        return self._archive().namelist()

    def _archive(self) -> zipfile.ZipFile:
        if self._zip is None:
            try:
                self._zip = zipfile.ZipFile(self.path)
            except (zipfile.BadZipFile, OSError) as e:
                raise TakeError(f"{self.path}: not a readable .r3d (a Record3D .r3d is a zip: {e}; the file is "
                                f"truncated or corrupt); export it again from Record3D") from None
        return self._zip

    def _read(self, name: str) -> bytes:
        if self.path.is_dir():
            return (self.path / name).read_bytes()
        try:
            return self._archive().read(name)
        except (zipfile.BadZipFile, KeyError, OSError, EOFError) as e:
            raise OSError(f"{name}: {e}") from None

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()
            self._zip = None

    # -- index ------------------------------------------------------------------------------------
    def build_index(self) -> RecordingIndex:
        names = set(self._names())
        meta_name = next((n for n in ("metadata", "metadata.json") if n in names), None)
        if meta_name is None:
            raise TakeError(f"{self.path}: Record3D export without its `metadata` file (intrinsics, fps, poses); "
                            f"export the recording again, or copy `metadata` from the .r3d into the folder")
        try:
            meta = json.loads(self._read(meta_name))
        except (OSError, ValueError) as e:
            raise TakeError(f"{self.path}: Record3D `metadata` cannot be read as JSON ({e})") from None
        w, h = int(meta.get("w", 0)), int(meta.get("h", 0))
        if w <= 0 or h <= 0 or len(meta.get("K", [])) != 9:
            raise TakeError(f"{self.path}: Record3D `metadata` needs w, h and K (9 numbers); it has "
                            f"{sorted(meta)}")
        K = np.asarray(meta["K"], float).reshape(3, 3).T  # column-major
        frames = sorted(n for n in (frame_number(x) for x in names if x.startswith("rgbd/") and x.endswith(".jpg"))
                        if n is not None)
        if not frames:
            raise TakeError(f"{self.path}: no colour frames (rgbd/N.jpg) in the Record3D export")
        fps = finite_or(meta.get("fps"), 30.0)
        stamps = meta.get("frameTimestamps")
        times = np.array([stamps[n] if isinstance(stamps, list) and n < len(stamps) else n / fps for n in frames],
                         float)
        fps, stamps_s, keys, status, message = place_on_time_axis(times, frames, fps, str(self.path))
        size = _jpg_size_of(self._read(f"rgbd/{frames[0]}.jpg"))
        if size is not None and size != (w, h):
            K = scale_intrinsics(K, (w, h), size)
            w, h = size
        notes: list[str] = []
        for i, n in enumerate(keys):
            if n is not None and f"rgbd/{n}.depth" not in names:
                status[i], message[i] = "missing_depth", f"rgbd/{n}.depth is missing"
        moved = _camera_motion(meta.get("poses"), keys)
        if moved is not None and np.nanmax(moved) > MOVED_M:
            notes.append(f"the camera moved {np.nanmax(moved) * 100:.1f} cm during the take (Record3D's poses); "
                         f"demoforge assumes a static camera: mount the phone and record again")
            for i, d in enumerate(moved):
                if d > MOVED_M and status[i] == "ok":
                    status[i], message[i] = "camera_moved", f"camera {d * 100:.1f} cm from its first pose"
        info = {"format": "record3d", "depth_integer_scale": None, "rgb_size": [w, h], "depth_size": _depth_size(meta),
                "max_camera_motion_m": None if moved is None else float(np.nanmax(moved))}
        return RecordingIndex(width=w, height=h, K=K.tolist(), fps=fps, timestamps_s=stamps_s, keys=keys,
                              status=status, message=message, notes=notes, info=info)

    # -- frames -----------------------------------------------------------------------------------
    def decode(self, index: RecordingIndex, wanted: list[int]
               ) -> Iterator[tuple[int, np.ndarray | None, np.ndarray | None, str]]:
        import cv2

        min_conf = int(self.options.get("min_confidence", 1))
        for i in wanted:
            n = index.keys[i]
            try:
                bgr = cv2.imdecode(np.frombuffer(self._read(f"rgbd/{n}.jpg"), np.uint8), cv2.IMREAD_COLOR)
            except OSError as e:
                yield i, None, None, f"rgbd/{n}.jpg: {e}"
                continue
            if bgr is None or bgr.shape[:2] != (index.height, index.width):
                yield i, None, None, f"rgbd/{n}.jpg cannot be decoded (corrupt, or not {index.width} x {index.height})"
                continue
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            depth, msg = self._depth(n, index, min_conf)
            yield i, rgb, depth, msg

    def _depth(self, n: int, index: RecordingIndex, min_conf: int) -> tuple[np.ndarray | None, str]:
        import cv2
        import lzfse

        try:
            raw = lzfse.decompress(self._read(f"rgbd/{n}.depth"))
        except (OSError, lzfse.error) as e:
            return None, f"rgbd/{n}.depth cannot be decompressed (LZFSE): {e}"
        d = np.frombuffer(raw, np.float32)
        size = _depth_shape(d.size, index.info.get("depth_size"), index.width, index.height)
        if size is None:
            return None, f"rgbd/{n}.depth has {d.size} values: not an image of the RGB's aspect ratio"
        d = d.reshape(size)
        try:
            conf = np.frombuffer(lzfse.decompress(self._read(f"rgbd/{n}.conf")), np.uint8)
        except (OSError, lzfse.error):
            conf = None
        if conf is not None and conf.size == d.size:
            d = np.where(conf.reshape(size) >= min_conf, d, 0.0).astype(np.float32)
        if size != (index.height, index.width):
            d = cv2.resize(d, (index.width, index.height), interpolation=cv2.INTER_NEAREST)
        return d, ""


def _depth_size(meta: dict) -> list[int] | None:
    dw, dh = meta.get("dw"), meta.get("dh")
    return [int(dh), int(dw)] if dw and dh else None


def _depth_shape(n: int, given: Any, w: int, h: int) -> tuple[int, int] | None:
    """(rows, cols) of a depth map of n values: the metadata's, else the RGB's aspect ratio."""
    if given and int(given[0]) * int(given[1]) == n:
        return int(given[0]), int(given[1])
    dw = int(round(np.sqrt(n * w / h)))
    if dw > 0 and n % dw == 0:
        return n // dw, dw
    return None


def _jpg_size_of(data: bytes) -> tuple[int, int] | None:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    return (img.shape[1], img.shape[0]) if img is not None else None


def _camera_motion(poses: Any, keys: list[Any]) -> np.ndarray | None:
    """Distance (m) of each frame's camera position from the first frame's (NaN without a pose)."""
    if not isinstance(poses, list) or not poses:
        return None
    try:
        p = np.asarray(poses, float)
    except (TypeError, ValueError):
        return None
    if p.ndim != 2 or p.shape[1] < 7:
        return None
    first = next((k for k in keys if k is not None and k < len(p)), None)
    if first is None:
        return None
    out = np.full(len(keys), np.nan)
    for i, k in enumerate(keys):
        if k is not None and k < len(p):
            out[i] = float(np.linalg.norm(p[k, 4:7] - p[first, 4:7]))
    return out


class Record3DSource(RecordingSource):
    """Record3D's ``.r3d`` file or its exported folder (``metadata`` + ``rgbd/``)."""

    name = "record3d"
    description = "Record3D export: .r3d (zip) or the exported folder (metadata + rgbd/N.jpg, N.depth, N.conf)"
    recording_cls = Record3DRecording

    @classmethod
    def claims(cls, path: Path) -> bool:
        if path.is_file():
            return path.suffix.lower() == ".r3d"
        return path.is_dir() and (path / "rgbd").is_dir() and not (path / "camera.json").is_file()
