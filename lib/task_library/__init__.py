"""Task library: the thesis's six dual-arm tasks as MuJoCo scenes with scripted human takes.

    from demoforge.lib.task_library import TASK_NAMES, get_task, Demo, Segment, Placement
    task = get_task("pouring")
    demo = task.scripted_demo(seed=0, mirror=False)
    result = task.replay(demo)        # physics replay, result.success / result.reason

See base.py for conventions (frames, mirroring), tasks.py for the tasks and scripting.py for how their
scripted takes move.
"""

from .base import Demo, Placement, ReplayResult, Segment, Task, TaskObject
from .tasks import TASKS

#: Bump when scenes, scripts or predicates change: it is part of every dependent stage's cache key.
TASK_LIBRARY_VERSION = "1.2.0"

TASK_NAMES = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


#: Registered task variants (Task.variant), by name: "<task>@<tag>"; looked up by get_task like a task,
#: so code that takes a task name (the robot simulator's scene cache, execute) runs them unchanged.
_VARIANTS: dict[str, Task] = {}


def register_variant(task: Task, tag: str) -> str:
    """Register a variant of a task under the name "<task.name>@<tag>" and return that name.  Registering
    the same name again replaces it (variants are deterministic functions of their tag)."""
    if not tag or "@" in tag or not tag.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"variant tag must be a non-empty alphanumeric string (with - or _), got {tag!r}")
    if task.name not in TASKS:
        raise ValueError(f"variant of unknown task {task.name!r}; known: {TASK_NAMES}")
    key = f"{task.name}@{tag}"
    _VARIANTS[key] = task
    return key


def get_task(name: str) -> Task:
    try:
        return TASKS[name]
    except KeyError:
        pass
    try:
        return _VARIANTS[name]
    except KeyError:
        hint = " (variants must be registered first: register_variant)" if "@" in str(name) else ""
        raise KeyError(f"unknown task {name!r}; known: {TASK_NAMES}{hint}") from None


__all__ = ["TASK_NAMES", "get_task", "register_variant", "Demo", "Segment", "Placement", "ReplayResult", "Task",
           "TaskObject"]
