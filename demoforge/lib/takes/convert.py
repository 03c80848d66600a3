"""A take written as a take folder (``demoforge convert``): the frames of any source on disk.

RGB as PNG; depth lossless: 16-bit PNG in the recording's own unit where its depth is integer
(RealSense z16, a ROS ``16UC1`` topic; ``depth_scale`` in camera.json), float32 ``.npy`` in metres
otherwise (Record3D, ``32FC1``). A dropped frame gets no files (the folder reader flags it missing).
camera.json carries the pose when the take has one; annotations.json, take.json and ground_truth/
come along. The folder is written under a temporary name and renamed at the end: a failure leaves
nothing behind.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Callable

import numpy as np

from demoforge.lib.takes.reader import iter_frames
from demoforge.lib.takes.types import Take, TakeError


def convert_take(take: Take, out: str | os.PathLike, progress: Callable[[int], None] | None = None,
                 batch_size: int = 8) -> dict:
    """Write ``take`` as a take folder at ``out`` (which must not exist or be empty); returns a summary."""
    import cv2

    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise TakeError(f"{out}: exists and is not empty; choose a new --out folder")
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "rgb").mkdir(parents=True)
    (tmp / "depth").mkdir()
    info = take.decoder.info if take.decoder is not None else {}
    scale = info.get("depth_integer_scale")
    written = 0
    try:
        for batch in iter_frames(take, batch_size=batch_size):
            for i, rgb, depth in zip(batch.indices, batch.rgb, batch.depth):
                name = f"{int(i):06d}"
                if not cv2.imwrite(str(tmp / "rgb" / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                   [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                    raise TakeError(f"{tmp}: cannot write frame {name}.png (disk full?)")
                if take.frames[int(i)].status in ("missing_depth", "unreadable_depth"):
                    pass
                elif scale:
                    units = np.rint(depth / np.float32(scale))
                    cv2.imwrite(str(tmp / "depth" / f"{name}.png"), np.clip(units, 0, 65535).astype(np.uint16))
                else:
                    np.save(tmp / "depth" / f"{name}.npy", depth.astype(np.float32))
                written += 1
                if progress is not None:
                    progress(1)
        _write_metadata(take, tmp, scale)
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"frames": written, "of": take.n_frames, "depth": "png16" if scale else "npy",
            "problems": take.status_counts()}


def _write_metadata(take: Take, folder: Path, scale: float | None) -> None:
    cam = take.camera
    obj = {"K": np.asarray(cam.K).tolist(), "width": cam.width, "height": cam.height, "fps": cam.fps}
    if scale:
        obj["depth_scale"] = float(scale)
    else:
        obj["depth_unit"] = "m"
    if cam.T_world_camera is not None:
        obj["T_world_camera"] = np.asarray(cam.T_world_camera).tolist()
        obj["pose_method"] = take.pose_method or "camera.json"
    obj["converted_from"] = {"path": str(take.path), "source": take.source, "notes": take.notes}
    (folder / "camera.json").write_text(json.dumps(obj, indent=2) + "\n")
    meta = take.meta_dir
    if meta is not None:
        for name in ("annotations.json", "take.json"):
            if (meta / name).is_file():
                shutil.copy2(meta / name, folder / name)
        if (meta / "ground_truth").is_dir():
            shutil.copytree(meta / "ground_truth", folder / "ground_truth")
