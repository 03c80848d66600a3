"""The physics replay of a scripted demonstration, through the simulator's frame loop.

    from demoforge.lib.sim.replay import replay
    result = replay(get_task("pouring").scripted_demo(0))
    result.success, result.reason

The demonstrator's hands (robots/hands.py: mocap pinch bodies, a held object welded to its hand while the
demonstration holds it) follow the demonstration's pinch frames as (n, 2, 8) actions, through the same
frame loop (loop.py) as every robot's execution (executor.py): pre-roll, action frames of
`ctrl_per_frame` control steps, settle phase. The verdict is the task's predicate on the final state and
the history of the demonstration's frames and the settled state, as the task library's replay always
judged it (lib/task_library's scripted takes are checked by it: tests/lib/task_library/test_task_library.py,
the synthetic takes' `replay_success`).

Kept from the task library's replay so that its verdicts and object poses do not change (an executor
episode differs in each): the scene is compiled with the demonstration's placement and its MJCF's own
solver options (MuJoCo's defaults: 100 iterations, island discovery on) and step, 0.00208333 s as the MJCF
writes it (the executor sets 1/480 s and its own solver options); the objects start where that MJCF puts
them (to its 6 significant digits); the hands blend their targets linearly (robots/hands.py); the
simulation never stops early. The settle phase runs whole 30 fps frames: round(settle_s * fps) of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from demoforge.lib.task_library import Demo, Task, get_task

from .executor import SimOptions, _schedule
from .loop import Records, preroll, record_frame, run_frames, settle
from .robots.base import Execution
from .robots.hands import DemoHands, HoldPlan
from .scene import SimScene

HANDS = DemoHands()


@dataclass
class ReplayResult:
    success: bool
    reason: str
    object_poses: np.ndarray  # (T, n_objects, 4, 4) simulated
    wall_time_s: float = 0.0
    # final_object_poses: (n_objects, 4, 4) after the settle phase; trace: (T, k, 3) the trace bodies' positions
    extra: dict = field(default_factory=dict)


def replay(demo: Demo, settle_s: float = 0.8, trace_bodies: tuple[str, ...] = (),
           task: Task | None = None) -> ReplayResult:
    """Physics replay of a scripted demonstration (module docstring): pinch frames drive the hands, a held
    object is welded to its hand while held (its pose relative to the hand taken from the simulator at the
    grasp frame). After the last frame the simulation runs `settle_s` more seconds, then the task's predicate
    is evaluated on the final state and the history (T + 1 poses: the T frames and the settled state).
    `trace_bodies`: extra body names whose world positions are recorded per frame into extra['trace']
    (T, k, 3). task: the demonstration's task (default get_task(demo.task); a variant's own Task)."""
    t0 = time.perf_counter()
    task = task if task is not None else get_task(demo.task)
    # the physics runs to its end: no stop at a hard failure (there is no robot to fail), nor at rest
    opt = SimOptions(robot=HANDS, settle_s=settle_s, stop_on_hard_failure=False, stop_when_settled=False)
    sc = SimScene(task, HANDS, None, placement=demo.placement)  # physics None: the MJCF's own options
    actions = demo.gripper_actions()
    n = len(actions)
    sch = _schedule(actions, demo.fps, opt, sc.spec, sc.model.opt.timestep)  # frame timing, targets offered
    plan = cast(HoldPlan, sc.binding.plan(sc, Execution(actions, demo.held_object), sch.quat, sch.targets_pos,
                                          sch.targets_wxyz, sch.cpf, demo.fps))
    sc.reset(None, np.concatenate([sch.pos[0], sch.quat[0]], axis=-1), np.zeros(2), plan)
    preroll(sc, opt.preroll_s)
    T = n + sch.settle_frames
    rec = Records(sc, T, opt, None)
    tr_ids = [sc.mj.mj_name2id(sc.model, sc.mj.mjtObj.mjOBJ_BODY, b) for b in trace_bodies]
    trace: list[np.ndarray] = []

    def on_frame(d):
        if len(trace) < n:
            trace.append(d.xpos[tr_ids])

    record_frame(sc, rec, 0, on_frame)
    plan.start(sc.data)  # the objects held from the first frame on (the pre-roll holds nothing)
    run_frames(sc, rec, opt, sch.sub, [()] * n, sch.targets_pos, None, None, plan.apply, n, on_frame)
    settle(sc, rec, opt, sch.sub, (), sch.pos[-1], None, None, n, T, on_frame)
    hist = np.concatenate([rec.hist[:n], rec.hist[-1:]], axis=0)
    ok, reason = task.success(sc.model, sc.data, hist)
    return ReplayResult(bool(ok), reason, hist[:-1], time.perf_counter() - t0,
                        extra={"final_object_poses": hist[-1], "trace": np.array(trace).reshape(n, len(tr_ids), 3)})


__all__ = ["HANDS", "ReplayResult", "replay"]
