"""The take's files: numbered frames, image and .npy headers read without decoding, the video found,
and an MP4 whose index was lost (a recording cut short) repaired."""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path
from typing import Iterator, Sequence
import numpy as np

from demoforge.lib.takes.types import TakeError


# ------------------------------------------------------------------------------------------------
# frame indexing
# ------------------------------------------------------------------------------------------------

_NUM = re.compile(r"(\d+)")


def frame_number(name: str) -> int | None:
    """The last run of digits in a file name's stem (``rgb_frame000363.png`` -> 363), or None."""
    nums = _NUM.findall(Path(name).stem)
    return int(nums[-1]) if nums else None


def list_files(folder: Path, exts: Sequence[str]) -> list[Path]:
    if not folder.is_dir():
        return []
    return [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in exts and not p.name.startswith(".")]


def numbered_files(files: list[Path], what: str, folder: Path) -> dict[int, Path] | None:
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


def png_size(path: Path) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) from a PNG's IHDR, or None if not a PNG."""
    with open(path, "rb") as f:
        head = f.read(29)
    if len(head) < 29 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    w, h = struct.unpack(">II", head[16:24])
    return w, h, head[24], head[25]


def jpg_size(path: Path) -> tuple[int, int] | None:
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


def image_header_size(path: Path) -> tuple[int, int] | None:
    s = png_size(path)
    if s is not None:
        return s[0], s[1]
    return jpg_size(path)


def npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype] | None:
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


def find_video(root: Path) -> Path | None:
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


def salvage_mp4(path: Path, camera: CameraInfo, out_dir: Path) -> tuple[Path, int] | None:
    """Recover the complete frames of an mp4 whose index (moov box, written last) was cut off.

    Works for MPEG-4 Part 2 video (OpenCV's ``mp4v`` writer, used by demoforge.lib.synth.take): the complete
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


def video_props(path: Path) -> tuple[int, int, int] | None:
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
