"""The scripted demonstrations executed by the ALOHA arms: outcome, failure class and time-scale per task
and hand, and the CPU time of planning the arms' motion (IK with its candidates, the transits and the
time-scaling: lib/sim/robots/arm_motion.py) per 100 demonstrated steps.

    .venv/bin/python scripts/measure_aloha_scripted.py [--seeds 4] [--hands 2f140 aloha] [--tasks pouring ...]
                                                       [--planning-only]

Each task's scripted demonstrations (seeds 0..N-1, plain and mirrored) at the task's base placement,
executed in physics (lib/sim execute, as `demoforge simulate` does); then the motion planning alone,
timed with the process's CPU clock (one core) after one warm-up pass. --planning-only: the timing alone
(no physics), the median of --repeats passes.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TASKS = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--hands", nargs="+", default=["2f140", "aloha"])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    ap.add_argument("--planning-only", action="store_true", help="only the motion planning's CPU time")
    ap.add_argument("--repeats", type=int, default=1, help="timed passes (the median is printed)")
    args = ap.parse_args()

    from demoforge.lib.task_library import get_task

    demos = {t: [get_task(t).scripted_demo(s, mirror=m) for s in range(args.seeds) for m in (False, True)]
             for t in args.tasks}
    if not args.planning_only:
        _physics(args, demos)
    _planning(args, demos)


def _physics(args, demos) -> None:
    from demoforge.lib.sim import SimOptions, execute
    from demoforge.lib.sim.robots import get_robot

    print("| task | hand | success | failure classes | time-scale (min-max) |")
    print("|---|---|---|---|---|")
    for hand in args.hands:
        robot = get_robot("aloha", hand)
        for t in args.tasks:
            results = [execute(t, d.placement.object_poses, d.gripper_actions(), options=SimOptions(robot=robot))
                       for d in demos[t]]
            classes = Counter(r.failure for r in results if not r.success)
            scales = [r.robot["time_scale"] for r in results if r.robot.get("time_scale") is not None]
            print(f"| {t} | {hand} | {sum(r.success for r in results)}/{len(results)} | "
                  f"{', '.join(f'{k} {v}' for k, v in classes.most_common()) or '-'} | "
                  f"{min(scales):.2f}-{max(scales):.2f} |", flush=True)


def _planning(args, demos) -> None:
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    robot = get_robot("aloha", "2f140")
    episodes = [(t, d.gripper_actions(), get_task(t).keypoints_world(d.placement.object_poses))
                for t in args.tasks for d in demos[t]]
    for t, a, k in episodes:  # warm-up: the solvers and their models
        robot.motion(t, a, k)
    times = []
    for _ in range(max(args.repeats, 1)):
        c0 = time.process_time()
        for t, a, k in episodes:
            robot.motion(t, a, k)
        times.append(time.process_time() - c0)
    cpu = float(np.median(times))
    steps = sum(len(a) for _, a, _ in episodes)
    median = f", the median of {len(times)} passes" if len(times) > 1 else ""
    print(f"\nmotion planning (2F-140): {cpu / steps * 100 * 1000:.1f} ms CPU per 100 demonstrated steps "
          f"({len(episodes)} episodes, {steps} steps, {cpu:.1f} s{median})")


if __name__ == "__main__":
    main()
