"""The annotation of a take as data: task definition, annotations.json, suggestions, status.

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
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

SIDES = ("left", "right")
RANGE_CONVENTION = "[start, end) 0-based frame indices, end exclusive"
#: The one-line state of a take whose object keypoints are not annotated (printed by ingest, augment).
NOT_ANNOTATED = "not annotated yet"
#: Object keypoints per scene in the episode tables (schemas/augment.py) and prompts: a custom task has these.
EPISODE_KEYPOINTS = 11
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")


def _err(msg: str) -> Exception:
    from demoforge.lib.takes import TakeError  # lazy: demoforge.lib.ingest's parser calls back into this module

    return TakeError(msg)


# ------------------------------------------------------------------------------------------------
# task definition
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TaskDefinition:
    """A task as the annotation needs it: named keypoints grouped by object, and each object's arm."""

    name: str
    object_names: tuple[str, ...]
    object_arms: tuple[str | None, ...]     # "left" | "right" per object; None = not stated (inferred)
    keypoint_names: tuple[str, ...]         # object by object
    keypoint_object: tuple[int, ...]        # object index per keypoint
    library: bool = False

    @property
    def n_keypoints(self) -> int:
        return len(self.keypoint_names)

    def object_arm_index(self) -> np.ndarray | None:
        """(n_objects,) 0 = left, 1 = right; None unless every object's arm is stated."""
        if any(a is None for a in self.object_arms):
            return None
        return np.array([SIDES.index(a) for a in self.object_arms], int)

    def to_json(self) -> dict:
        return {"name": self.name, "library": self.library,
                "objects": [{"name": o, "arm": a,
                             "keypoints": [k for k, ko in zip(self.keypoint_names, self.keypoint_object) if ko == i]}
                            for i, (o, a) in enumerate(zip(self.object_names, self.object_arms))]}

    def keypoints_local(self, keypoints_world: np.ndarray) -> np.ndarray:
        """(K, 3) each keypoint in its object's frame, for a custom task: the object frame is the
        world frame translated to the object's keypoint centroid at the annotated frame (a custom
        object has no model; its annotated shape is its model)."""
        kp = np.asarray(keypoints_world, float)
        ko = np.asarray(self.keypoint_object, int)
        cent = np.stack([kp[ko == o].mean(0) for o in range(len(self.object_names))])
        return kp - cent[ko]

    def workspace(self, keypoints_world: np.ndarray, positions: np.ndarray, margin_xy: float = 0.30,
                  margin_z: float = 0.15) -> np.ndarray:
        """(2, 3) xyz box for a custom task's episodes: the demonstration's extent (keypoints and
        gripper positions) grown by the margins (the library tasks have a measured box instead)."""
        pts = np.concatenate([np.asarray(keypoints_world, float).reshape(-1, 3),
                              np.asarray(positions, float).reshape(-1, 3)])
        pts = pts[np.isfinite(pts).all(1)]
        m = np.array([margin_xy, margin_xy, margin_z])
        return np.stack([pts.min(0) - m, pts.max(0) + m])


def _definition(name: str, objects: Sequence[tuple[str, str | None, Sequence[str]]], library: bool,
                where: str) -> TaskDefinition:
    if not isinstance(name, str) or not _NAME.match(name):
        raise _err(f"{where}: task name must be letters, digits, _ . - (starting with a letter or digit), got {name!r}")
    objs = [(o, a, list(k)) for o, a, k in objects if k]
    if not objs:
        raise _err(f"{where}: the task has no keypoints; give at least one object keypoint")
    onames = [o for o, _, _ in objs]
    if len(set(onames)) != len(onames):
        raise _err(f"{where}: object names must be unique, got {onames}")
    if len(onames) > 2:
        raise _err(f"{where}: a two-handed task has at most 2 objects (one per arm), got {onames}")
    kn = [k for _, _, ks in objs for k in ks]
    if len(set(kn)) != len(kn):
        dup = sorted({k for k in kn if kn.count(k) > 1})
        raise _err(f"{where}: keypoint names must be unique, repeated: {dup}")
    for k in [*onames, *kn]:
        if not isinstance(k, str) or not _NAME.match(k):
            raise _err(f"{where}: names must be letters, digits, _ . - (no spaces or commas), got {k!r}")
    if not library and len(kn) != EPISODE_KEYPOINTS:
        raise _err(f"{where}: a task of your own needs {EPISODE_KEYPOINTS} object keypoints, got {len(kn)}: the "
                   f"episode tables and the prompts hold {EPISODE_KEYPOINTS} per scene (the thesis's format); "
                   f"split them over the two objects, e.g. 5 + 6")
    for o, a, _ in objs:
        if a is not None and a not in SIDES:
            raise _err(f"{where}: object {o!r}: arm must be 'left' or 'right', got {a!r}")
    return TaskDefinition(name=name, object_names=tuple(onames), object_arms=tuple(a for _, a, _ in objs),
                          keypoint_names=tuple(kn),
                          keypoint_object=tuple(i for i, (_, _, ks) in enumerate(objs) for _ in ks),
                          library=library)


def library_task(name: str) -> TaskDefinition:
    """A task of the library (demoforge.lib.task_library), its keypoints in the library's order."""
    from demoforge.lib.task_library import TASK_NAMES, get_task

    if name not in TASK_NAMES:
        raise _err(f"unknown task {name!r}; choose one of {', '.join(TASK_NAMES)}, or --task custom "
                   f"--keypoints NAME,NAME,... (or --task-file FILE) for a task of your own")
    t = get_task(name)
    arms = t.object_arm(False)
    ko = np.asarray(t.keypoint_object)
    objects = [(o, SIDES[int(arms[i])], [k for k, j in zip(t.keypoint_names, ko) if j == i])
               for i, o in enumerate(t.object_names)]
    return _definition(name, objects, True, f"task {name}")


def custom_task(keypoints: Sequence[str] | str, name: str = "custom") -> TaskDefinition:
    """A user-defined task from keypoint names; ``object:keypoint`` puts a keypoint on an object
    (at most two objects), a bare name goes on the first object ("object_a", reassignable in the page)."""
    items = [s.strip() for s in (keypoints.split(",") if isinstance(keypoints, str) else keypoints)]
    items = [s for s in items if s]
    if not items:
        raise _err("--keypoints: give the object keypoint names, comma separated (e.g. cup:rim,cup:base,bowl:rim)")
    objects: dict[str, list[str]] = {}
    for it in items:
        obj, _, kp = it.rpartition(":")
        objects.setdefault(obj or "object_a", []).append(kp)
    return _definition(name, [(o, None, ks) for o, ks in objects.items()], False, "--keypoints")


def parse_task_section(obj: Any, where: str = "annotations.json") -> TaskDefinition:
    """Validate a ``task`` object ({"name", "library"?, "objects": [{"name", "arm"?, "keypoints"}]})."""
    if not isinstance(obj, dict) or "name" not in obj:
        raise _err(f"{where}: 'task' must be an object {{\"name\": ..., \"objects\": [...]}}")
    name = obj["name"]
    objects = obj.get("objects")
    library = bool(obj.get("library", False))
    if objects is None:
        return library_task(name)
    if not isinstance(objects, list) or not all(isinstance(o, dict) for o in objects):
        raise _err(f"{where}: task.objects must be a list of {{\"name\", \"arm\", \"keypoints\"}} objects")
    parsed = []
    for i, o in enumerate(objects):
        ks = o.get("keypoints")
        if not isinstance(ks, list) or not all(isinstance(k, str) for k in ks):
            raise _err(f"{where}: task.objects[{i}].keypoints must be a list of keypoint names")
        parsed.append((o.get("name", f"object_{i}"), o.get("arm"), ks))
    d = _definition(name, parsed, library, where)
    if library:
        ref = library_task(name)
        if d.keypoint_names != ref.keypoint_names:
            raise _err(f"{where}: task {name!r} is a library task; its keypoints must be {list(ref.keypoint_names)}")
    return d


def load_task_file(path: str | os.PathLike) -> TaskDefinition:
    """A task file: JSON {"name": ..., "objects": [{"name", "arm" (optional), "keypoints": [...]}]}."""
    p = Path(path)
    try:
        obj = json.loads(p.read_text())
    except OSError as e:
        raise _err(f"{p}: cannot read the task file: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise _err(f"{p}: the task file is not valid JSON ({e})") from None
    if isinstance(obj, dict) and "objects" not in obj:
        raise _err(f"{p}: a task file needs 'objects': [{{\"name\": ..., \"arm\": \"left\"|\"right\", "
                   f"\"keypoints\": [...]}}]")
    return parse_task_section(obj, str(p))


def task_for_take(take: Any, task: str | None = None, keypoints: str | None = None,
                  task_file: str | os.PathLike | None = None) -> TaskDefinition:
    """The task to annotate a take with: a task file, ``custom`` + keypoints, a library name, else
    what the take's annotations.json (or a synthetic take.json) says."""
    if task_file is not None:
        return load_task_file(task_file)
    if task is not None and task.startswith("custom"):
        name = task.split(":", 1)[1] if ":" in task else "custom"
        if keypoints:
            return custom_task(keypoints, name)
        stored = getattr(getattr(take, "annotations", None), "task", None)
        if stored is not None and not stored.library:
            return stored
        raise _err("--task custom needs --keypoints NAME,NAME,... (object:name puts a keypoint on an object) "
                   "or a --task-file")
    if keypoints:
        raise _err("--keypoints is for --task custom (a task of your own); library tasks have fixed keypoints")
    if task is not None:
        return library_task(task)
    stored = getattr(getattr(take, "annotations", None), "task", None)
    if stored is not None:
        return stored
    meta_task = (getattr(take, "meta", None) or {}).get("task")
    if meta_task:
        return library_task(str(meta_task))
    from demoforge.lib.task_library import TASK_NAMES

    raise _err(f"which task does this take show? give --task NAME ({', '.join(TASK_NAMES)}), or "
               f"--task custom --keypoints NAME,NAME,... for a task of your own")


# ------------------------------------------------------------------------------------------------
# annotations.json
# ------------------------------------------------------------------------------------------------

def build_annotations(task: TaskDefinition, points: Mapping[str, Sequence[float]] | None, frame: int,
                      closed_ranges: Mapping[str, Sequence[Sequence[int]]] | None, n_frames: int,
                      keep: Mapping[str, Any] | None = None) -> dict:
    """The annotations.json object, validated. ``points``: {keypoint name: [u, v]} (placed ones only;
    written in the task's order); ``keep``: an existing file's object, whose other keys are kept."""
    from demoforge.lib.takes import parse_annotations

    points = dict(points or {})
    unknown = sorted(set(points) - set(task.keypoint_names))
    if unknown:
        raise _err(f"keypoint(s) {unknown} are not keypoints of task {task.name!r} ({list(task.keypoint_names)})")
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
    from demoforge.lib.ingest.gripper_open_close import gripper_state

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
    from demoforge.lib.ingest.object_keypoints import backproject_keypoints_detailed

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
