"""How closely the held objects move as demonstrated when the arms execute an episode (issue 42's measure of
the object-centric retargeting: the object's motion, not the hand's, is what must be kept).

    .venv/bin/python scripts/measure_object_motion.py [--warehouse W --episodes 20] [--seeds 4] [--tasks ...]

For each episode (the scripted demonstrations, seeds 0..N-1 plain and mirrored; with --warehouse also a
sample of each task's database) executed in physics by the ALOHA arms with the 2F-140: the demonstrated
motion of every object an arm holds (lib/sim/robots/retarget.object_trajectories on the episode's own
actions) against the simulated object, at each executed frame inside that arm's window while the
demonstration holds it, from 0.5 s after the close on (the gripper's closing time) (the executed frame's demonstrated step from the time-scaling). Position: the
object's origin; rotation: the smallest angle to the demonstrated orientation over the object's symmetry
turns (any turn about its axis: the axis's angle). Successful episodes only; median and 95th percentile.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SETTLE_STEPS = 15  # a grasp is measured from 0.5 s after the close on (the 2F-140 takes about 0.45 s to close)
TASKS = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip((np.einsum("...ij,...ij->...", Ra, Rb) - 1.0) / 2.0, -1.0, 1.0)))


def object_errors(task, actions, keypoints0, result, motion) -> tuple[list, list]:
    """(position errors m, rotation errors degrees) of the held objects over the executed frames."""
    from demoforge.lib.sim.robots.aloha.retargeting import object_poses_at_start
    from demoforge.lib.geometry import pose7_to_transform
    from demoforge.lib.sim.robots.retarget import object_trajectories, rot_z
    from demoforge.lib.trajectories.segmentation import held_objects

    held = held_objects(actions, keypoints0, task.keypoint_object)
    demo = object_trajectories(pose7_to_transform(actions[..., :7]), actions[..., 7] < 0.5, held,
                               object_poses_at_start(task, keypoints0))
    sim = result.object_poses
    m = min(len(sim), len(motion.s))
    step = np.clip(np.round(motion.s[:m]).astype(int), 0, len(actions) - 1)
    pos_err, rot_err = [], []
    for a in range(2):
        w0, w1 = motion.windows[a]
        closed_for = np.zeros(len(actions), int)  # steps the hand has held its object
        for t in range(len(actions)):
            closed_for[t] = closed_for[t - 1] + 1 if held[t, a] >= 0 and t else int(held[t, a] >= 0)
        for i in np.flatnonzero((step >= w0) & (step < w1) & (motion.s[:m] >= 0)):
            o = held[step[i], a]
            if o < 0 or closed_for[step[i]] < SETTLE_STEPS:
                continue
            want, got = demo[step[i], o], sim[i, o]
            pos_err.append(float(np.linalg.norm(want[:3, 3] - got[:3, 3])))
            sym = task.objects[o].symmetry
            if sym == 0:
                rot_err.append(float(np.degrees(np.arccos(np.clip(want[:3, 2] @ got[:3, 2], -1.0, 1.0)))))
            else:
                turns = rot_z(2.0 * np.pi * np.arange(sym) / sym)[:, :3, :3]
                rot_err.append(float(_angle(want[:3, :3] @ turns, got[None, :3, :3]).min()))
    return pos_err, rot_err


def episodes(args):
    """(task, label, actions, keypoints0) of the episodes to measure."""
    from demoforge.lib.task_library import get_task

    for t in args.tasks:
        for s in range(args.seeds):
            for mirror in (False, True):
                d = get_task(t).scripted_demo(s, mirror=mirror)
                yield t, "scripted", d.gripper_actions(), get_task(t).keypoints_world(d.placement.object_poses)
        if args.warehouse:
            from demoforge.schemas.reads.episodes import load_episodes

            sel = load_episodes(args.warehouse, t)
            pick = np.sort(np.random.default_rng(1).choice(len(sel.lengths), args.episodes, replace=False))
            starts = np.concatenate([[0], np.cumsum(sel.lengths)])
            for i in pick:
                yield t, "database", sel.poses[starts[i]:starts[i + 1]].astype(float), sel.keypoints[i]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    ap.add_argument("--warehouse", default=None, help="also measure a sample of each task's database here")
    ap.add_argument("--episodes", type=int, default=20, help="episodes per task from --warehouse")
    ap.add_argument("--robot", default="aloha+2f140", help="aloha+2f140 (default) or grippers: the reference whose "
                    "windows are the arms' (the same frames are compared)")
    args = ap.parse_args()

    from demoforge.lib.sim import SimOptions, execute
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    robot = get_robot("aloha", "2f140")  # its motion gives the windows, and the frames' demonstrated steps
    runner = robot if args.robot == "aloha+2f140" else get_robot("grippers")
    opt = SimOptions(robot=runner, keep_trajectory=True)
    errs: dict = {}
    for t, label, actions, kp in episodes(args):
        r = execute(t, kp, actions, options=opt)
        if not r.success:
            continue
        motion = robot.motion(t, actions, kp)
        if runner is not robot:  # the grippers run the demonstrated frames as they are
            motion.s = np.arange(len(actions), dtype=float)
        p, q = object_errors(get_task(t), actions, kp, r, motion)
        e = errs.setdefault((t, label), [[], [], 0])
        e[0] += p
        e[1] += q
        e[2] += 1
    print("| task | episodes | successful episodes measured | position error median / p95 (mm) | "
          "rotation error median / p95 (degrees) |")
    print("|---|---|---|---|---|")
    for (t, label), (p, q, n) in sorted(errs.items()):
        if p:
            print(f"| {t} | {label} | {n} | {np.median(p) * 1000:.1f} / {np.percentile(p, 95) * 1000:.1f} | "
                  f"{np.median(q):.1f} / {np.percentile(q, 95):.1f} |")


if __name__ == "__main__":
    main()
