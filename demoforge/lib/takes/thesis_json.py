"""The keypoint JSON of the thesis's public code (Jiayun-Zhang/Hand_keypoint_detector, run.py), read
into per-frame hands."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence
import numpy as np

from demoforge.lib.takes.types import TakeError
from demoforge.lib.takes.metadata import load_json
from demoforge.lib.takes.media import frame_number


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
    obj = load_json(p, "keypoint JSON")
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
