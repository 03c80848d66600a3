"""Choose where the two ViperX bases stand at each task's table (lib/sim/robots/aloha/placement.py).

For every candidate position of the left arm's base (the right arm's is its mirror image), the IK of
lib/sim/robots/ik.py tracks every step of the task's scripted demonstrations (seeds 0-3, plain and
mirrored: the arms swap roles), warm-started along each episode as the simulator runs it. A step is
reachable when both pinch poses end within 1 cm and 5 degrees of their targets. Prints, per task, the
candidates ranked by the share of reachable steps (then of fully reachable episodes) and the best one.

    .venv/bin/python scripts/place_aloha_bases.py [--hand aloha|2f140] [--tasks pouring ...] [--seeds 4] [--physics]

--physics ranks the candidates by the scripted demonstrations the arms execute successfully in MuJoCo
instead (lib/sim execute, with the arms' own grasps and transits, as `demoforge simulate` runs them): a
placement whose every step is reachable can still lay an object on the arm's own shoulder.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

XS = (-0.35, -0.45, -0.55)
YS = (-0.15, -0.05, 0.05, 0.15, 0.25)
ZS = (0.0, 0.15)  # on the table top, or on a 15 cm riser
YAW = math.pi / 2  # the waist turns +-180 degrees: the base yaw only moves where that range ends


def demos(task: str, seeds: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(object poses, actions) of the task's scripted demonstrations, seeds 0..seeds-1, plain and mirrored."""
    from demoforge.lib.task_library import get_task

    t = get_task(task)
    return [(d.placement.object_poses, d.gripper_actions())
            for d in (t.scripted_demo(s, m) for s in range(seeds) for m in (False, True))]


def score(base, hand: str, episodes: list[np.ndarray]) -> dict:
    from demoforge.lib.sim.robots.aloha import AlohaRobot

    robot = AlohaRobot(hand=hand, bases=(base, base.mirrored()))
    ik = robot.ik("pouring")  # the bases are given: the task does not matter
    steps = ok_steps = ok_eps = 0
    for a in episodes:
        sol = ik.solve(a)
        bad = sol.failed_steps().any(axis=1)
        steps += len(bad)
        ok_steps += int((~bad).sum())
        ok_eps += int(not bad.any())
    return {"x": base.x, "y": base.y, "z": base.z, "steps_ok": ok_steps / steps, "episodes_ok": ok_eps / len(episodes)}


def physics_score(base, hand: str, task: str, scripted: list) -> dict:
    """The candidate's share of scripted demonstrations (objects, actions) the arms execute successfully."""
    from collections import Counter

    from demoforge.lib.sim import SimOptions, execute
    from demoforge.lib.sim.robots.aloha import AlohaRobot

    robot = AlohaRobot(hand=hand, bases=(base, base.mirrored()))
    results = [execute(task, objects, actions, options=SimOptions(robot=robot)) for objects, actions in scripted]
    failures = Counter(r.failure for r in results if not r.success)
    ok = sum(r.success for r in results) / len(results)
    return {"x": base.x, "y": base.y, "z": base.z, "episodes_ok": ok, "failures": dict(failures)}


def main() -> None:
    from demoforge.lib.sim.robots.aloha.model import BasePose
    from demoforge.lib.task_library import TASK_NAMES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hand", default="aloha", choices=("aloha", "2f140"))
    ap.add_argument("--tasks", nargs="*", default=list(TASK_NAMES))
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--json", type=Path, help="also write every candidate's scores here")
    ap.add_argument("--physics", action="store_true", help="rank by the scripted demonstrations executed in physics")
    a = ap.parse_args()
    everything = {}
    for task in a.tasks:
        eps = demos(task, a.seeds)
        t0 = time.perf_counter()
        bases = [BasePose(x, y, z, YAW) for x, y, z in itertools.product(XS, YS, ZS)]
        if a.physics:
            rows = [physics_score(b, a.hand, task, eps) for b in bases]
        else:
            rows = [score(b, a.hand, [actions for _, actions in eps]) for b in bases]
        rows.sort(key=lambda r: (-r.get("steps_ok", 0.0), -r["episodes_ok"]))
        everything[task] = rows
        print(f"\n{task} ({len(eps)} scripted episodes, hand {a.hand}, {time.perf_counter() - t0:.0f} s)")
        for r in rows[:5]:
            print(f"  x {r['x']:+.2f}  y {r['y']:+.2f}  z {r['z']:.2f}  " + (
                f"succeed {100 * r['episodes_ok']:5.1f} %  {r['failures'] or ''}" if a.physics else
                f"steps reachable {100 * r['steps_ok']:5.1f} %  episodes {100 * r['episodes_ok']:5.1f} %"))
    if a.json:
        a.json.write_text(json.dumps(everything, indent=1))


if __name__ == "__main__":
    main()
