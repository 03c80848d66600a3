"""Benchmark cases of the ALOHA arms (lib/sim/robots): inverse kinematics and physics, stage `arms`.

ik_warm_started_100_steps   fast = ArmsIK.solve along each 100-step episode, warm-started (each step
                            from the last one's joints, one QP iteration most of the time); baseline =
                            the same poses solved step by step from scratch (the geometric seeds, then
                            mink until converged), as one would solve isolated poses. Both on one core
                            (one process); the check: every step of both within 1 cm and 5 degrees.
                            Episodes: 100-step windows of the six tasks' scripted demonstrations (seeds
                            0-1, plain and mirrored) that the arms reach at every step.
closed_form_ik_batch        fast = ViperXBatchIK.solve (lib/sim/robots/aloha/closed_form.py) on 100,000 pinch
                            poses [x y z qx qy qz qw] at once (quaternions to matrices included), all 8
                            branches with their joint-range margins; baseline = the same poses one at a
                            time with ViperXGeometry.solutions (seeds.py: its 4 branches, no ranges), timed
                            on 2,000 poses (500 quick) and scaled. The check: the batch's first 4 branches
                            are the baseline's angles (modulo 2 pi). Poses: the left arm's base at the
                            pouring table, positions up to 0.6 m around it (within reach and beyond), any
                            orientation. Both on one core.
screening_10000_episodes    fast = screen_episodes (lib/sim/robots/aloha/screening.py) on a pouring database of
                            10,000 episodes (the scripted demonstration of seed 0 augmented: 5,000 translated,
                            5,000 mirrored and translated, one core) for the arms with the 2F-140, its numba
                            kernels compiled (or loaded from their cache) on 32 of them first; baseline =
                            the arms' motion planner (AlohaRobot.motion: windows, grasp choice, mink IK along
                            every step, retiming; no physics) on 6 of them (2 quick) spread over the database,
                            scaled to 10,000. The check: every episode the screening lets through has both
                            arms' grasps feasible in the planner's own choice.
physics_aloha_<task>        fast = execute_many(workers=1) with the `aloha` robot carrying the 2F-140
                            (IK, joint position actuators, arm links in the scene); baseline = the
                            floating `grippers` on the same episodes: ratio < 1 is what the arms cost
                            more per episode. Episodes: the task's scripted demonstrations (seeds 0-1,
                            plain and mirrored); outcomes differ (the arms fail what they cannot reach
                            and stop there), so both run to the end of the episode
                            (stop_on_hard_failure off) and there is no outcome check.
"""

from __future__ import annotations

import numpy as np

from demoforge.bench.cases_sim import scripted_episodes, timed_pair
from demoforge.bench.timing import BenchCase, one_core
from demoforge.lib.geometry import quat_to_matrix, random_quaternions
from demoforge.lib.sim import SimOptions
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.sim.robots.aloha import AlohaRobot
from demoforge.lib.sim.robots.aloha.closed_form import ViperXBatchIK
from demoforge.lib.sim.robots.aloha.screening import screen_episodes
from demoforge.lib.sim.robots.aloha.seeds import ViperXGeometry
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

TASKS = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")
WINDOW = 100


def reachable_windows(n: int, hand: str = "2f140") -> list[tuple[str, np.ndarray]]:
    """Up to n (task, (100, 2, 8) poses) windows of scripted demonstrations that the arms reach throughout."""
    robot = get_robot("aloha", hand)
    out = []
    for seed in (0, 1):
        for task in TASKS:
            for mirror in (False, True):
                acts = get_task(task).scripted_demo(seed, mirror).gripper_actions()
                ok = ~robot.ik(task).solve(acts).failed_steps().any(axis=1)
                good = np.convolve(ok.astype(int), np.ones(WINDOW, int), "valid") == WINDOW
                if good.any():
                    s = int(np.flatnonzero(good)[len(np.flatnonzero(good)) // 2])
                    out.append((task, acts[s:s + WINDOW]))
                if len(out) >= n:
                    return out
    return out


def _ik_setup(n: int):
    robot = get_robot("aloha", "2f140")
    windows = reachable_windows(n)

    def fast():
        return [robot.ik(task).solve(w) for task, w in windows]

    def baseline():
        return [[robot.ik(task).solve(w[t:t + 1]) for t in range(len(w))] for task, w in windows]

    return fast, baseline


def _ik_check(fast, baseline) -> None:
    assert not any(s.failed_steps().any() for s in fast), "a warm-started step off its target"
    assert not any(s.failed_steps().any() for ep in baseline for s in ep), "a cold-started step off its target"


def _closed_form_setup(n: int):
    robot = AlohaRobot(hand="2f140")
    ik, base = robot.ik("pouring"), robot.bases_for("pouring")[0]
    geometry = ViperXGeometry(ik.model)
    batch = ViperXBatchIK(geometry, ik.lower[:6], ik.upper[:6])
    rng = np.random.default_rng(5)
    pos = np.array([base.x, base.y, base.z + 0.3]) + rng.uniform(-0.6, 0.6, (n, 3))
    poses = np.concatenate([pos, random_quaternions(n, rng)], axis=1)

    def fast():
        return batch.solve(base, poses[:, :3], quat_to_matrix(poses[:, 3:7])).q

    def baseline():
        return np.array([geometry.solutions(base, p) for p in poses])

    return fast, baseline


def _closed_form_check(fast, baseline) -> None:
    """The batch's first four branches are seeds.py's solutions, each angle modulo 2 pi (the batch shifts
    angles into the joints' ranges)."""
    diff = (fast[:, :4] - baseline + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(diff).max() < 1e-9, f"the batch IK differs from seeds.py by {np.abs(diff).max():.3g} rad"


_DATABASES: dict = {}


def screening_database(task: str, n: int):
    """(actions (n, T, 2, 8), lengths (n,), keypoints (n, K, 3)) of a database of n episodes built from the task's
    scripted demonstration of seed 0 (half of the augmented ones mirrored), as `demoforge augment` builds one."""
    key = (task, n)
    if key not in _DATABASES:
        t = get_task(task)
        b = generate_episodes(from_scripted_demo(t, t.scripted_demo(0)), n=n - 1, n_mirrored=n // 2, seed=0,
                              workers=1)
        _DATABASES[key] = (np.asarray(b.actions, float), np.asarray(b.lengths), np.asarray(b.keypoints, float))
    return _DATABASES[key]


def _screening_setup(size: int):
    def setup(n: int):
        robot = get_robot("aloha", "2f140")
        robot.retargeting("pouring")  # the closed form and the IK model, built once outside the timing
        actions, lengths, kp = screening_database("pouring", size)
        if n < size:  # (the whole database as it is: a copy of its 460 MB is no part of screening it)
            pick = np.unique(np.linspace(0, size - 1, n).round().astype(int))
            actions, lengths, kp = actions[pick], lengths[pick], kp[pick]
        # numba's kernels compiled (or loaded from their cache) outside the timing, as the IK model above
        warm = slice(None, None, max(1, len(actions) // 32))
        screen_episodes(robot, "pouring", actions[warm], lengths[warm], kp[warm])

        def fast():
            with one_core():
                return screen_episodes(robot, "pouring", actions, lengths, kp)

        def baseline():
            return [robot.motion("pouring", actions[e, :lengths[e]], kp[e]) for e in range(len(actions))]

        return fast, baseline

    return setup


def _screening_check(fast, baseline) -> None:
    """The screening lets through only episodes whose arms' grasps the planner finds feasible."""
    for ok, motion in zip(fast.executable, baseline):
        assert not ok or all(a.feasible for a in motion.grasps.arms), "screened in, but the planner's grasp fails"


def _physics_setup(task: str, frames: int | None):
    def setup(n: int):
        arms = SimOptions(robot=get_robot("aloha", "2f140"), stop_on_hard_failure=False)
        return timed_pair(task, scripted_episodes(task, n, frames), arms, SimOptions(stop_on_hard_failure=False),
                          workers=1)

    return setup


def cases(quick: bool) -> list[BenchCase]:
    ik = BenchCase("arms", "ik_warm_started_100_steps", 4 if quick else 12, "episodes",
                   "the same poses solved step by step from scratch (seeds, then mink to convergence), one core",
                   _ik_setup, check=_ik_check, repeats=1 if quick else 3)
    closed = BenchCase("arms", "closed_form_ik_batch", 100_000, "poses",
                       "the same poses one at a time with ViperXGeometry.solutions (seeds.py), one core",
                       _closed_form_setup, check=_closed_form_check, repeats=1 if quick else 3,
                       baseline_size=500 if quick else 2_000)
    screen = BenchCase("arms", "screening_10000_episodes", 2_000 if quick else 10_000, "episodes",
                       "the arms' motion planner (windows, grasps, mink IK per step, retiming) on a few, one core",
                       _screening_setup(2_000 if quick else 10_000), check=_screening_check, repeats=1,
                       baseline_size=2 if quick else 6)
    base = "the floating grippers on the same episodes (ratio < 1: what the arms cost more), one process"
    if quick:
        return [ik, closed, screen, BenchCase("arms", "physics_aloha_pouring_2s", 2, "episodes", base,
                                              _physics_setup("pouring", 60), repeats=1)]
    return [ik, closed, screen] + [BenchCase("arms", f"physics_aloha_{task}", 4, "episodes", base,
                                     _physics_setup(task, None), repeats=1) for task in TASKS]
