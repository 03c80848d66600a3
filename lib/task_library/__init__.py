"""Task library: the thesis's six dual-arm tasks as MuJoCo scenes with scripted human takes.

    from lib.task_library import TASK_NAMES, get_task, Demo, Segment, Placement
    task = get_task("pouring")
    demo = task.scripted_demo(seed=0, mirror=False)
    result = task.replay(demo)        # physics replay, result.success / result.reason

See base.py for conventions (frames, mirroring) and tasks.py for the tasks.
"""

from .base import Demo, Placement, ReplayResult, Segment, Task, TaskObject
from .tasks import TASKS

#: Bump when scenes, scripts or predicates change: it is part of every dependent stage's cache key.
TASK_LIBRARY_VERSION = "1.2.0"

TASK_NAMES = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


def get_task(name: str) -> Task:
    try:
        return TASKS[name]
    except KeyError:
        raise KeyError(f"unknown task {name!r}; known: {TASK_NAMES}") from None


__all__ = ["TASK_NAMES", "get_task", "Demo", "Segment", "Placement", "ReplayResult", "Task", "TaskObject"]
