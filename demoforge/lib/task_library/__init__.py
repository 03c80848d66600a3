"""Task library: the thesis's six dual-arm tasks as MuJoCo scenes with scripted human takes.

    from demoforge.lib.task_library import TASK_NAMES, get_task, Demo, Segment, Placement
    task = get_task("pouring")
    demo = task.scripted_demo(seed=0, mirror=False)

    from demoforge.lib.sim.replay import replay   # the physics replay runs in the simulator (lib/sim sits above)
    result = replay(demo)             # result.success / result.reason

See base.py for conventions (frames, mirroring), tasks.py for the tasks and scripting.py for how their
scripted takes move.
"""

from demoforge.lib.task_library import tasks as _tasks  # noqa: F401  (registers the six tasks)
from demoforge.lib.task_library.base import (TASK_NAMES, Demo, Placement, Segment, Task, TaskObject, get_task,
                                             register_variant)

#: Bump when scenes, scripts or predicates change: it is part of every dependent stage's cache key.
TASK_LIBRARY_VERSION = "1.2.0"

__all__ = ["TASK_NAMES", "TASK_LIBRARY_VERSION", "get_task", "register_variant", "Demo", "Segment", "Placement",
           "Task", "TaskObject"]
