"""The annotation of a take as data: annotations.json, suggestions, status (the task definition it
writes is :mod:`demoforge.lib.takes.task_definition`).

``annotations.json`` (docs/takes.md; the keys ingest reads are validated by
:func:`demoforge.lib.ingest.parse_annotations`)::

    {
      "object_keypoints_2d": {"frame": 0, "names": [...], "uv": [[u, v], ...]},   # pixels, OpenCV
      "gripper_closed_ranges": {"left": [[start, end], ...], "right": [...]},   # [start, end) frames
      "range_convention": "[start, end) 0-based frame indices, end exclusive",
      "task": {"name": "pouring", "library": true,                              # written by the page
               "objects": [{"name": "bottle", "arm": "right", "keypoints": ["bottle_base", ...]},
                           {"name": "cup", "arm": "left", "keypoints": [...]}]}
    }

``task`` says which task the take shows (so ``ingest`` / ``augment`` need no ``--task``), which
keypoint belongs to which object and which arm acts on each object. For a task of the library the
names and order come from the library; a custom task (``library: false``) defines its own, and its
objects' local keypoint geometry is taken from the annotated first frame (see
:meth:`TaskDefinition.keypoints_local`). Keypoint order = the objects' keypoints, object by object.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from demoforge.lib.ingest.gripper_open_close import gripper_state
from demoforge.lib.ingest.object_keypoints import backproject_keypoints_detailed
from demoforge.lib.takes.metadata import parse_annotations
from demoforge.lib.takes.task_definition import SIDES, TaskDefinition
from demoforge.lib.takes.types import TakeError

RANGE_CONVENTION = "[start, end) 0-based frame indices, end exclusive"
#: The one-line state of a take whose object keypoints are not annotated (printed by ingest, augment).
NOT_ANNOTATED = "not annotated yet"

# ------------------------------------------------------------------------------------------------
# annotations.json
# ------------------------------------------------------------------------------------------------

def build_annotations(task: TaskDefinition, points: Mapping[str, Sequence[float]] | None, frame: int,
                      closed_ranges: Mapping[str, Sequence[Sequence[int]]] | None, n_frames: int,
                      keep: Mapping[str, Any] | None = None) -> dict:
    """The annotations.json object, validated. ``points``: {keypoint name: [u, v]} (placed ones only;
    written in the task's order); ``keep``: an existing file's object, whose other keys are kept."""
    points = dict(points or {})
    unknown = sorted(set(points) - set(task.keypoint_names))
    if unknown:
        raise TakeError(f"keypoint(s) {unknown} are not keypoints of task {task.name!r} ({list(task.keypoint_names)})")
    out: dict[str, Any] = {k: v for k, v in (keep or {}).items()
                           if k not in ("object_keypoints_2d", "gripper_closed_ranges", "task", "range_convention")}
    names = [k for k in task.keypoint_names if k in points]
    if names:
        out["object_keypoints_2d"] = {"frame": int(frame), "names": names,
                                      "uv": [[float(points[k][0]), float(points[k][1])] for k in names]}
    ranges = {s: sorted([int(a), int(b)] for a, b in (closed_ranges or {}).get(s, [])) for s in SIDES}
    out["gripper_closed_ranges"] = ranges
    out["range_convention"] = RANGE_CONVENTION
    out["task"] = task.to_json()
    parse_annotations(out, "annotations.json", n_frames=n_frames)  # the reader's own checks
    return out


def write_annotations(path: str | os.PathLike, obj: Mapping[str, Any]) -> Path:
    """Write annotations.json atomically (temp file in the same folder, fsync, rename)."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, indent=2)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


# ------------------------------------------------------------------------------------------------
# suggestions, clicked points, status
# ------------------------------------------------------------------------------------------------

def mask_to_ranges(mask: np.ndarray) -> list[list[int]]:
    """Runs of True in a 1D mask as [start, end) ranges."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]


def suggest_closed_ranges(fingertip_distance: np.ndarray) -> dict[str, list[list[int]]]:
    """The automatic open/close method's closed ranges per hand, from (T, 2) fingertip distances (m)."""
    d = np.asarray(fingertip_distance, float)
    if d.ndim != 2 or d.shape[1] != 2:
        raise ValueError(f"fingertip_distance must be (T, 2), got {d.shape}")
    if d.shape[0] == 0 or not np.isfinite(d).any():
        return {s: [] for s in SIDES}
    g = gripper_state(d, "auto")
    return {s: mask_to_ranges(g[:, h] < 0.5) for h, s in enumerate(SIDES)}


def point_info(uv: np.ndarray, depth: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray) -> list[dict]:
    """Per clicked pixel: the robust depth (5x5 median of valid pixels, as ingest reads it), the
    camera- and world-frame point, whether the clicked pixel itself has depth, and a warning."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    r = backproject_keypoints_detailed(uv, depth, K, T_world_camera)
    H, W = depth.shape
    out = []
    for i, (u, v) in enumerate(uv):
        iu, iv = int(round(u)), int(round(v))
        inside = 0 <= iu < W and 0 <= iv < H
        px = float(depth[iv, iu]) if inside else float("nan")
        pixel_ok = bool(np.isfinite(px) and px > 0)
        if not r.valid[i]:
            warning = f"invalid depth: {r.reasons[i]}; click a point on the object's surface with depth"
        elif not pixel_ok:
            warning = "no depth at this pixel: the value is the median of its valid neighbours"
        else:
            warning = ""
        out.append({"u": float(u), "v": float(v), "valid": bool(r.valid[i]), "pixel_depth_valid": pixel_ok,
                    "depth_m": None if not r.valid[i] else float(r.depth[i]),
                    "camera": None if not r.valid[i] else [float(x) for x in r.points_camera[i]],
                    "world": None if not r.valid[i] else [float(x) for x in r.points_world[i]],
                    "warning": warning})
    return out


@dataclass(frozen=True)
class AnnotationStatus:
    annotated: bool
    detail: str = ""          # what is missing, empty when annotated


def annotation_status(take: Any) -> AnnotationStatus:
    """Whether the take's object keypoints are annotated: annotations.json places every keypoint of
    its task (or, naming no task, has object keypoints). The same rule for synthetic takes, whose
    generator writes the file (their ingest then uses the exact ground-truth points)."""
    ann = getattr(take, "annotations", None)
    if ann is None:
        return AnnotationStatus(False, "no annotations.json")
    placed = list(ann.object_keypoint_names) if len(ann.object_keypoints_uv) else []
    if not placed:
        return AnnotationStatus(False, "no object keypoints in annotations.json")
    task = getattr(ann, "task", None)
    if task is not None:
        missing = [k for k in task.keypoint_names if k not in placed]
        if missing:
            return AnnotationStatus(False, f"{len(placed)} of {task.n_keypoints} object keypoints placed, "
                                           f"missing {', '.join(missing)}")
    return AnnotationStatus(True)


def not_annotated_message(take_path: str | os.PathLike, detail: str = "") -> str:
    """The one line ingest warns with and augment stops with."""
    extra = f" ({detail})" if detail else ""
    return f"{take_path}: {NOT_ANNOTATED}{extra}: run demoforge annotate {take_path}"
