"""camera.json and annotations.json: parsed and checked, each problem named by file and key."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any
import numpy as np

from demoforge.lib.takes.task_definition import parse_task_section
from demoforge.lib.takes.types import Annotations, CameraInfo, DEFAULT_DEPTH_SCALE, DEFAULT_FPS, TakeError


# ------------------------------------------------------------------------------------------------
# camera.json and annotations.json
# ------------------------------------------------------------------------------------------------

def load_json(path: Path, what: str) -> Any:
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


def parse_camera(obj: Any, path: str | os.PathLike = "camera.json", require_pose: bool = True) -> CameraInfo:
    """Validate a camera.json object. Raises :class:`TakeError` naming the key and the fix.

    ``require_pose=False`` accepts a camera.json without ``T_world_camera`` (``T_world_camera`` None: a
    take to calibrate, ``demoforge calibrate``)."""
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
    T = parse_pose(obj, path, require_pose)
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


def parse_pose(obj: dict, path: Path, require: bool = True) -> np.ndarray | None:
    """camera.json's ``T_world_camera`` checked as a rigid 4x4 camera-to-world transform; None when it is
    absent and not required."""
    if obj.get("T_world_camera") is None and "T_world_camera" in obj:
        obj = {k: v for k, v in obj.items() if k != "T_world_camera"}
    if "T_world_camera" not in obj:
        if not require:
            return None
        raise TakeError(f"{path}: key 'T_world_camera' is missing (the camera's 4x4 pose in the table frame); "
                        f"run `demoforge calibrate {path.parent}` to find it (a printed board on the table, or "
                        f"the table plane), or add it as a 4x4 nested list")
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
    return T


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
        task = parse_task_section(obj["task"], str(path))
        unknown = [n for n in names if n not in task.keypoint_names]
        if unknown:
            raise TakeError(f"{path}: object_keypoints_2d.names {unknown} are not keypoints of the file's task "
                            f"{task.name!r} ({list(task.keypoint_names)})")
    if okp is None and gcr is None and task is None:
        raise TakeError(f"{path}: has neither 'object_keypoints_2d' nor 'gripper_closed_ranges'")
    return Annotations(object_keypoints_frame=frame, object_keypoint_names=names,
                       object_keypoints_uv=uv, gripper_closed_ranges=ranges, raw=obj, task=task)
