"""Benchmark cases for the robot simulator (lib/sim): episodes checked per second.

fast     = execute_many(workers=2) with the default SimOptions: no constraint-island discovery, the
           settle phase ended once the scene is at rest, contact and finger-command look-ups on
           Python lists (lib/sim/scene.py PhysicsOptions, executor.py SimOptions); timestep
           1/480 s, implicitfast (coarser steps change marginal outcomes: PhysicsOptions).
baseline = the previous settings and loop, same worker count: LEGACY_PHYSICS (islands on) and the
           full 0.8 s settle after the last action.
Episodes: the tasks' original scripted demos (seeds 0-3, plain and mirrored), which succeed under
both settings (the check asserts identical outcomes), so the numbers are the full-length cost.

`breakdown(task)` measures where an episode's time goes (MuJoCo's own timers, mjData.timer, with a
time callback installed only for that measurement): physics (mj_step) split into collision
detection, constraint construction, constraint solver and the rest of the pipeline, the executor's
Python (wall time - mj_step time), physics steps and mean contacts per step.  The sim cases print it
(demoforge/bench/run.py runs with log_prints) and pass it as the case's `notes` where demoforge.bench.timing's
BenchCase has such a field.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import replace

from demoforge.bench.timing import BenchCase
from demoforge.lib.sim import SimOptions, execute, execute_many
from demoforge.lib.sim.scene import LEGACY_PHYSICS, get_scene
from demoforge.lib.task_library import get_task

TASKS = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


def _episodes(task_name: str, n: int, frames: int | None):
    t = get_task(task_name)
    eps = []
    for i in range(n):  # the original demos: seeds 0, 0, 1, 1, ... x (plain, mirrored)
        d = t.scripted_demo(i // 2 % 4, bool(i % 2))
        a = d.gripper_actions()
        eps.append((d.placement.object_poses, a if frames is None else a[:frames]))
    return eps


def options():
    """(fast, baseline) SimOptions of the benchmark."""
    fast = SimOptions(keep_trajectory=False)
    return fast, replace(fast, physics=LEGACY_PHYSICS, stop_when_settled=False)


def breakdown(task_name: str, episodes: int = 2, frames: int | None = None, sim_options=None) -> dict:
    """Where one episode's time goes, averaged over `episodes` scripted demos (single process).

    Returns seconds per episode: wall, physics (mj_step), collision, constraint_make, solver,
    physics_other, python; and steps, contacts (mean per recorded frame), constraint rows (mean)."""
    import mujoco
    import numpy as np

    opt = sim_options or options()[0]
    eps = _episodes(task_name, episodes, frames)
    sc = get_scene(task_name, opt.robot, opt.physics)
    execute(task_name, *eps[0], options=opt)  # warm caches outside the measurement
    T = mujoco.mjtTimer
    acc = dict.fromkeys(("wall", "physics", "collision", "constraint_make", "solver", "steps"), 0.0)
    ncon, nefc = [], []

    def count_constraints(d):
        ncon.append(d.ncon)
        nefc.append(d.nefc)

    mujoco.set_mjcb_time(time.perf_counter)  # MuJoCo's timers stay zero without a clock callback
    try:
        for obj, act in eps:
            t0 = time.perf_counter()
            r = execute(task_name, obj, act, options=opt, on_frame=count_constraints)
            acc["wall"] += time.perf_counter() - t0
            tm = sc.data.timer  # reset by mj_resetData at the episode's start: this episode only
            acc["physics"] += tm[T.mjTIMER_STEP].duration
            acc["collision"] += tm[T.mjTIMER_POS_COLLISION].duration
            acc["constraint_make"] += tm[T.mjTIMER_POS_MAKE].duration
            acc["solver"] += tm[T.mjTIMER_CONSTRAINT].duration
            acc["steps"] += r.physics_steps
    finally:
        mujoco.set_mjcb_time(None)
    out = {k: v / len(eps) for k, v in acc.items()}
    out["physics_other"] = out["physics"] - out["collision"] - out["constraint_make"] - out["solver"]
    out["python"] = out["wall"] - out["physics"]
    out["contacts"] = float(np.mean(ncon)) if ncon else 0.0
    out["constraint_rows"] = float(np.mean(nefc)) if nefc else 0.0
    return out


def format_breakdown(b: dict) -> str:
    w = b["wall"] or 1.0
    pct = lambda k: 100.0 * b[k] / w  # noqa: E731
    return (f"per episode {b['wall'] * 1e3:.0f} ms (timers on): physics {pct('physics'):.0f}% "
            f"[collision {pct('collision'):.0f}%, constraint build {pct('constraint_make'):.0f}%, "
            f"solver {pct('solver'):.0f}%, rest of pipeline {pct('physics_other'):.0f}%], "
            f"Python {pct('python'):.0f}%; {b['steps']:.0f} steps, "
            f"{1e6 * b['physics'] / max(b['steps'], 1):.0f} us/step, {b['contacts']:.1f} contacts, "
            f"{b['constraint_rows']:.0f} constraint rows")


def timed_pair(task_name: str, eps: list, fast_opt, base_opt, workers: int):
    """(fast, baseline): execute_many of the same episodes with two SimOptions, returning the failures."""

    def fast():
        return [r.failure for r in execute_many(task_name, eps, workers=workers, options=fast_opt)]

    def baseline():
        return [r.failure for r in execute_many(task_name, eps, workers=workers, options=base_opt)]

    return fast, baseline


def scripted_episodes(task_name: str, n: int, frames: int | None = None):
    """n (object poses, actions) of the task's scripted demonstrations: seeds 0, 0, 1, 1, ... (plain, mirrored)."""
    return _episodes(task_name, n, frames)


def _setup(task_name: str, frames: int | None):
    def setup(size: int):
        return timed_pair(task_name, _episodes(task_name, size, frames), *options(), workers=2)

    return setup


def _notes(task_name: str, frames: int | None):
    def notes() -> str:
        fast_opt, base_opt = options()
        text = (f"fast: {format_breakdown(breakdown(task_name, frames=frames, sim_options=fast_opt))}; "
                f"baseline: {format_breakdown(breakdown(task_name, frames=frames, sim_options=base_opt))}")
        print(f"sim {task_name}: {text}")
        return text

    return notes


def _check(a, b):
    # same episodes, same outcomes: the speed settings must not change a scripted demo's result
    assert a == b, f"outcomes differ: fast {a} vs baseline {b}"


BASELINE = "previous settings (constraint islands on, full 0.8 s settle), same 2 worker processes"


def _case(name: str, task_name: str, size: int, frames: int | None, **kw) -> BenchCase:
    setup, notes = _setup(task_name, frames), _notes(task_name, frames)
    if "notes" in {f.name for f in dataclasses.fields(BenchCase)}:
        return BenchCase("sim", name, size, "episodes", BASELINE, setup, check=_check, notes=notes, **kw)
    printed: list[str] = []

    def setup_and_print(n: int):  # the harness has no notes field: print the breakdown once instead
        if not printed:
            printed.append(notes())
        return setup(n)

    return BenchCase("sim", name, size, "episodes", BASELINE, setup_and_print, check=_check, **kw)


def cases(quick: bool) -> list[BenchCase]:
    if quick:
        return [_case("execute_many_trash_in_bin_2s", "trash_in_bin", 4, 60, repeats=1)]
    return [_case(f"execute_many_{task}", task, 8, None, repeats=1) for task in TASKS]
