"""Benchmark cases for the robot simulator (lib/robot_sim): episodes checked per second.

fast     = execute_many(workers=2): one compiled model per worker process, MjData reset per episode,
           4 control updates per 30 fps frame with mj_step(nstep=...) between them, contacts scanned
           through precomputed geom-pair tables, simulation stopped at the first hard failure.
           Episodes: the tasks' original demos (seeds 0-3, plain and mirrored), which all succeed, so
           the early stop does not shorten them: the numbers are the full-length cost.
baseline = the straightforward loop: one process, the scene XML recompiled for every episode and one
           Python-level mj_step call (and mocap / command update) per physics step (same model and
           solver; the mocap targets are updated 16 instead of 4 times per frame).
"""

from __future__ import annotations

from dataclasses import replace

from lib.benchmarking import BenchCase


def _episodes(task_name: str, n: int, frames: int | None):
    from lib.task_library import get_task

    t = get_task(task_name)
    eps = []
    for i in range(n):  # the original demos: seeds 0, 0, 1, 1, ... x (plain, mirrored)
        d = t.scripted_demo(i // 2 % 4, bool(i % 2))
        a = d.gripper_actions()
        eps.append((d.placement.object_poses, a if frames is None else a[:frames]))
    return eps


def _setup(task_name: str, frames: int | None):
    def setup(size: int):
        from lib.robot_sim import SimOptions, execute, execute_many
        from lib.robot_sim import scene as scene_mod

        eps = _episodes(task_name, size, frames)
        opt = SimOptions()
        base_opt = replace(opt, ctrl_per_frame=10**6, keep_trajectory=False)  # one control update per step

        def fast():
            return [r.row()["failure"] for r in execute_many(task_name, eps, workers=2, options=opt)]

        def baseline():
            out = []
            for obj, act in eps:
                scene_mod.clear_cache()  # recompile per episode
                out.append(execute(task_name, obj, act, options=base_opt).failure)
            return out

        return fast, baseline

    return setup


def _check(a, b):
    assert len(a) == len(b)


def cases(quick: bool) -> list[BenchCase]:
    if quick:
        return [BenchCase("sim", "execute_many_open_container_2s", 4, "episodes",
                          "1 process, XML recompiled per episode, one mj_step call per physics step",
                          _setup("open_container", 60), check=_check, repeats=1)]
    return [BenchCase("sim", f"execute_many_{task}", 8, "episodes",
                      "1 process, XML recompiled per episode, one mj_step call per physics step",
                      _setup(task, None), check=_check, repeats=1, baseline_size=2)
            for task in ("pouring", "trash_in_bin")]
