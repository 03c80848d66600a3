"""Why the ALOHA arms cannot follow an episode, and what would let them: the IK of every scripted
demonstration (seeds 0-3, plain and mirrored) at the task's base placement, per hand.

For each task and hand it prints how many episodes the arms reach at every step (1 cm, 5 degrees)
as they are, without the servos' speed limits, without the steps before the first grasp and after
the last release (the demonstrator's hands coming from and going back to rest, more than 1 s away
from any grasp), and without both; and what stops the first failing step of each episode: the target
beyond the stretched arm, a joint at the end of its range, a joint at its speed limit, or none of these.

    .venv/bin/python scripts/measure_aloha_reach.py [--seeds 4] [--tasks pouring ...]
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

FPS = 30.0


def task_window(actions: np.ndarray, margin_s: float = 1.0) -> np.ndarray:
    """(n,) the steps from margin_s before the first close to margin_s after the last open (any arm)."""
    closed = (actions[:, :, 7] < 0.5).any(axis=1)
    keep = np.zeros(len(actions), bool)
    if closed.any():
        m = int(round(margin_s * FPS))
        first, last = int(np.argmax(closed)), len(closed) - 1 - int(np.argmax(closed[::-1]))
        keep[max(0, first - m):last + m + 1] = True
    return keep


def cause(sol) -> str:
    first = sol.first_failure()
    if first is None:
        return "reached"
    t, arm = first[0], first[1]
    if sol.out_of_reach is not None and sol.out_of_reach[t, arm]:
        return "beyond reach"
    if sol.at_range_limit[t, arm]:
        return "range limit"
    return "speed limit" if sol.at_speed_limit[t, arm] else "other"


def measure(task: str, hand: str, seeds: int) -> dict:
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    ik = get_robot("aloha", hand).ik(task)
    counts, causes = Counter(), Counter()
    for s in range(seeds):
        for mirror in (False, True):
            acts = get_task(task).scripted_demo(s, mirror).gripper_actions()
            sol = ik.solve(acts)
            causes[cause(sol)] += 1
            window = task_window(acts)
            speed = ik.speed.copy()
            ik.speed = speed * 100.0
            try:
                free = ik.solve(acts)
            finally:
                ik.speed = speed
            for name, s_ in (("as is", sol), ("no speed limit", free)):
                bad = s_.failed_steps().any(axis=1)
                counts[name] += int(not bad.any())
                counts[name + ", grasp window"] += int(not bad[window].any())
            counts["episodes"] += 1
    return {"counts": dict(counts), "causes": dict(causes)}


def main() -> None:
    from demoforge.lib.task_library import TASK_NAMES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--tasks", nargs="*", default=list(TASK_NAMES))
    a = ap.parse_args()
    print("| task | hand | episodes | reached as is | without speed limits | grasp window only | both | "
          "first failure: beyond reach / range limit / speed limit / other |")
    print("|---|---|---|---|---|---|---|---|")
    for task in a.tasks:
        for hand in ("aloha", "2f140"):
            r = measure(task, hand, a.seeds)
            c, k = r["counts"], r["causes"]
            print(f"| {task} | {hand} | {c['episodes']} | {c['as is']} | {c['no speed limit']} | "
                  f"{c['as is, grasp window']} | {c['no speed limit, grasp window']} | "
                  f"{k.get('beyond reach', 0)} / {k.get('range limit', 0)} / {k.get('speed limit', 0)} / "
                  f"{k.get('other', 0)} |", flush=True)


if __name__ == "__main__":
    main()
