"""The ``task`` section of a take's ``annotations.json``: which task the take shows, which keypoint belongs
to which object and which arm acts on each object (docs/takes.md)::

    "task": {"name": "pouring", "library": true,
             "objects": [{"name": "bottle", "arm": "right", "keypoints": ["bottle_base", ...]},
                         {"name": "cup", "arm": "left", "keypoints": [...]}]}

For a task of the library the names and order come from the library; a custom task (``library: false``)
defines its own, and its objects' local keypoint geometry is taken from the annotated first frame (see
:meth:`TaskDefinition.keypoints_local`). Keypoint order = the objects' keypoints, object by object.
Read with the rest of the file by :func:`demoforge.lib.takes.metadata.parse_annotations`; written by the
annotate page (:mod:`demoforge.lib.annotate`).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from demoforge.lib.takes.types import TakeError
from demoforge.lib.task_library import TASK_NAMES, get_task

SIDES = ("left", "right")
#: Object keypoints per scene in the episode tables (schemas/augment.py) and prompts: a custom task has these.
EPISODE_KEYPOINTS = 11
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")


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
        raise TakeError(f"{where}: task name must be letters, digits, _ . - (starting with a letter or digit), got {name!r}")
    objs = [(o, a, list(k)) for o, a, k in objects if k]
    if not objs:
        raise TakeError(f"{where}: the task has no keypoints; give at least one object keypoint")
    onames = [o for o, _, _ in objs]
    if len(set(onames)) != len(onames):
        raise TakeError(f"{where}: object names must be unique, got {onames}")
    if len(onames) > 2:
        raise TakeError(f"{where}: a two-handed task has at most 2 objects (one per arm), got {onames}")
    kn = [k for _, _, ks in objs for k in ks]
    if len(set(kn)) != len(kn):
        dup = sorted({k for k in kn if kn.count(k) > 1})
        raise TakeError(f"{where}: keypoint names must be unique, repeated: {dup}")
    for k in [*onames, *kn]:
        if not isinstance(k, str) or not _NAME.match(k):
            raise TakeError(f"{where}: names must be letters, digits, _ . - (no spaces or commas), got {k!r}")
    if not library and len(kn) != EPISODE_KEYPOINTS:
        raise TakeError(f"{where}: a task of your own needs {EPISODE_KEYPOINTS} object keypoints, got {len(kn)}: the "
                   f"episode tables and the prompts hold {EPISODE_KEYPOINTS} per scene (the thesis's format); "
                   f"split them over the two objects, e.g. 5 + 6")
    for o, a, _ in objs:
        if a is not None and a not in SIDES:
            raise TakeError(f"{where}: object {o!r}: arm must be 'left' or 'right', got {a!r}")
    return TaskDefinition(name=name, object_names=tuple(onames), object_arms=tuple(a for _, a, _ in objs),
                          keypoint_names=tuple(kn),
                          keypoint_object=tuple(i for i, (_, _, ks) in enumerate(objs) for _ in ks),
                          library=library)


def library_task(name: str) -> TaskDefinition:
    """A task of the library (demoforge.lib.task_library), its keypoints in the library's order."""
    if name not in TASK_NAMES:
        raise TakeError(f"unknown task {name!r}; choose one of {', '.join(TASK_NAMES)}, or --task custom "
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
        raise TakeError("--keypoints: give the object keypoint names, comma separated (e.g. cup:rim,cup:base,bowl:rim)")
    objects: dict[str, list[str]] = {}
    for it in items:
        obj, _, kp = it.rpartition(":")
        objects.setdefault(obj or "object_a", []).append(kp)
    return _definition(name, [(o, None, ks) for o, ks in objects.items()], False, "--keypoints")


def parse_task_section(obj: Any, where: str = "annotations.json") -> TaskDefinition:
    """Validate a ``task`` object ({"name", "library"?, "objects": [{"name", "arm"?, "keypoints"}]})."""
    if not isinstance(obj, dict) or "name" not in obj:
        raise TakeError(f"{where}: 'task' must be an object {{\"name\": ..., \"objects\": [...]}}")
    name = obj["name"]
    objects = obj.get("objects")
    library = bool(obj.get("library", False))
    if objects is None:
        return library_task(name)
    if not isinstance(objects, list) or not all(isinstance(o, dict) for o in objects):
        raise TakeError(f"{where}: task.objects must be a list of {{\"name\", \"arm\", \"keypoints\"}} objects")
    parsed = []
    for i, o in enumerate(objects):
        ks = o.get("keypoints")
        if not isinstance(ks, list) or not all(isinstance(k, str) for k in ks):
            raise TakeError(f"{where}: task.objects[{i}].keypoints must be a list of keypoint names")
        parsed.append((o.get("name", f"object_{i}"), o.get("arm"), ks))
    d = _definition(name, parsed, library, where)
    if library:
        ref = library_task(name)
        if d.keypoint_names != ref.keypoint_names:
            raise TakeError(f"{where}: task {name!r} is a library task; its keypoints must be {list(ref.keypoint_names)}")
    return d


def load_task_file(path: str | os.PathLike) -> TaskDefinition:
    """A task file: JSON {"name": ..., "objects": [{"name", "arm" (optional), "keypoints": [...]}]}."""
    p = Path(path)
    try:
        obj = json.loads(p.read_text())
    except OSError as e:
        raise TakeError(f"{p}: cannot read the task file: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise TakeError(f"{p}: the task file is not valid JSON ({e})") from None
    if isinstance(obj, dict) and "objects" not in obj:
        raise TakeError(f"{p}: a task file needs 'objects': [{{\"name\": ..., \"arm\": \"left\"|\"right\", "
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
        raise TakeError("--task custom needs --keypoints NAME,NAME,... (object:name puts a keypoint on an object) "
                   "or a --task-file")
    if keypoints:
        raise TakeError("--keypoints is for --task custom (a task of your own); library tasks have fixed keypoints")
    if task is not None:
        return library_task(task)
    stored = getattr(getattr(take, "annotations", None), "task", None)
    if stored is not None:
        return stored
    meta_task = (getattr(take, "meta", None) or {}).get("task")
    if meta_task:
        return library_task(str(meta_task))

    raise TakeError(f"which task does this take show? give --task NAME ({', '.join(TASK_NAMES)}), or "
               f"--task custom --keypoints NAME,NAME,... for a task of your own")
