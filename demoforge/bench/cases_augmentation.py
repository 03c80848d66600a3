"""Benchmark cases for augmentation and retrieval (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demoforge.bench.timing import BenchCase
from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories import augmentation as au, retrieval as rt
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
from demoforge.lib.trajectories.augmentation.servable import generate_servable
from demoforge.schemas.core import write_table


def _source():
    t = get_task("empty_vase")  # a 317-step two-arm take
    return from_scripted_demo(t, t.scripted_demo(0))


def cases(quick: bool) -> list[BenchCase]:
    n_aug = 2_000 if quick else 10_000

    def aug_setup(n):
        src = _source()
        b = au.generate_episodes(src, n=n - 1, n_mirrored=(n - 1) // 2, seed=0, materialize=False)

        def fast():  # parameters, keypoints, validity and all actions (materialised, float64)
            out = au.generate_episodes(src, n=n - 1, n_mirrored=(n - 1) // 2, seed=0, materialize=True)
            return out.actions

        def baseline():  # per-episode, per-step, per-arm 4x4 matrix loop on the same parameters
            acts = []
            for i in range(len(b)):
                g = b.groups[0] if i < b.groups[0].row1 else b.groups[-1]
                acts.append(au.transform_demo_loop(g.src, g.plan, b.params[i], b.pivots[i]))
            return np.stack(acts)

        return fast, baseline

    def aug_check(a, b):
        np.testing.assert_allclose(a[..., :3], b[..., :3], atol=1e-9)

    def ret_setup(n_db, n_q=20):
        def setup(n):
            rng = np.random.default_rng(0)
            kp = rng.uniform(-0.3, 0.5, size=(n, 11, 3))
            idx = rt.KeypointIndex(kp)
            qs = rng.uniform(-0.3, 0.5, size=(n_q, 11, 3))

            def fast():
                return np.stack([idx.query(q, 3).ids[0] for q in qs])

            def baseline():
                return np.stack([rt.mse_brute_force(kp, idx.ids, q, 3)[0] for q in qs])

            return fast, baseline
        return setup

    def ret_check(a, b):
        np.testing.assert_array_equal(a, b)

    n_q = 20
    out = [
        BenchCase("augmentation", "10k episodes of a 317-step two-arm demo (generate + validate + materialise)",
                  n_aug + 1 if not quick else n_aug, "episodes",
                  "per-episode, per-step Python loop of 4x4 matrix products", aug_setup, aug_check,
                  repeats=1 if quick else 2, baseline_size=21),
        BenchCase("retrieval", f"top-3 keypoint MSE over 10k episodes ({n_q} queries)", 10_000, "episodes",
                  "Python loop over episodes, sorted", ret_setup(10_000, n_q), ret_check, repeats=3,
                  baseline_size=1_000),
    ]
    if not quick:
        out.append(BenchCase("retrieval", f"top-3 keypoint MSE over 1M episodes ({n_q} queries)", 1_000_000,
                             "episodes", "Python loop over episodes, sorted", ret_setup(1_000_000, n_q), ret_check,
                             repeats=2, baseline_size=10_000))
    out.append(_episode_steps_write_case(quick))
    out.append(_servable_case(quick))
    return out


def _servable_case(quick: bool) -> BenchCase:
    """A database drawn where the arms can serve it (servable.py; trash_in_bin: 57 % of the uniform draw
    served): fast = each round's candidates screened together (screen_episodes on batches); baseline = the same
    draw with every candidate screened alone, as a per-episode rejection loop would. The check: the same
    placements and verdicts."""
    from demoforge.lib.sim.robots import get_robot  # lazy: the arms' models load mujoco
    from demoforge.lib.sim.robots.aloha.screening import screen_episodes

    task = "trash_in_bin"

    def setup(n: int):
        arms = get_robot("aloha", "2f140")
        arms.retargeting(task)  # the closed form and the IK model, built once outside the timing
        t = get_task(task)
        src = from_scripted_demo(t, t.scripted_demo(0))

        def batched(batch, rows):
            return screen_episodes(arms, task, batch.episode_actions(rows), batch.lengths[rows],
                                   batch.keypoints[rows]).executable

        def alone(batch, rows):
            return np.array([batched(batch, rows[i:i + 1])[0] for i in range(len(rows))], bool)

        def draw(serves):
            out = generate_servable(src, serves, n=n - 1, n_mirrored=(n - 1) // 2, seed=0)
            return out.served, out.batch.params

        return (lambda: draw(batched)), (lambda: draw(alone))

    def check(a, b):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])

    return BenchCase("augmentation", "servable_draw_trash_in_bin", 500 if quick else 2_000, "episodes",
                     "the same draw, every candidate screened alone (a per-episode rejection loop), one core",
                     setup, check, repeats=1, baseline_size=50 if quick else 100)


def _episode_steps_write_case(quick: bool) -> BenchCase:
    """Writing the episode_steps table of 10k episodes: validated and atomic, against row-by-row Python."""
    n = 2_000 if quick else 10_000

    def write_setup(k: int):
        from demoforge.tasks.augment import episode_steps_columns  # lazy: prefect

        task = get_task("empty_vase")
        batch = generate_episodes(from_scripted_demo(task, task.scripted_demo(0)), n=k - 1,
                                  n_mirrored=(k - 1) // 2, seed=0, materialize=True)
        tmp = folder_removed_at_exit("demoforge-bench-")

        def fast():
            return write_table("episode_steps", episode_steps_columns("empty_vase", "bench", batch), tmp)[0].rows

        def baseline():  # one Python row per step, then pyarrow and Parquet
            rows = [{"task": "empty_vase", "take": "bench", "episode_id": int(e), "step": s,
                     "action": batch.actions[e, s].astype(np.float32).tolist()}
                    for e in range(len(batch)) for s in range(int(batch.lengths[e]))]
            (tmp / "base").mkdir(exist_ok=True)
            pq.write_table(pa.Table.from_pylist(rows), tmp / "base" / "data.parquet")
            return len(rows)

        return fast, baseline

    return BenchCase("augmentation", "write episode_steps of 10k episodes (validated, atomic)", n + 1 if not quick else n,
                         "episodes", "one Python dict per step -> pyarrow -> Parquet", write_setup,
                         repeats=1, baseline_size=200)
