"""Writing a take's camera pose where the take keeps its camera metadata: a take folder's camera.json
(its other keys kept), a recording's side folder camera.json (demoforge.lib.takes.sources.sidecar_dir)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from demoforge.lib.takes.types import Take


def pose_file(take: Take) -> Path:
    return (take.meta_dir or take.path) / "camera.json"


def write_pose(take: Take, T_world_camera: np.ndarray, method: str, details: dict | None = None) -> Path:
    """Set T_world_camera (and ``pose_method``, ``calibration``: how it was found) atomically."""
    path = pose_file(take)
    obj = json.loads(path.read_text()) if path.is_file() else {}
    obj["T_world_camera"] = np.round(np.asarray(T_world_camera, float), 9).tolist()
    obj["pose_method"] = method
    obj["calibration"] = details or {}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(obj, indent=2) + "\n")
    os.replace(tmp, path)
    return path
