"""Benchmark cases of the exports (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib.exports import frame_in_episode, next_poses
from demoforge.lib.exports.lerobot import STAT_KEYS, episode_stats, features, lerobot_stats
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes


def cases(quick: bool) -> list[BenchCase]:
    n = 2_000 if quick else 10_000

    def stats_setup(k: int):
        task = get_task("empty_vase")  # a 317-step two-arm take
        batch = generate_episodes(from_scripted_demo(task, task.scripted_demo(0)), n=k - 1, n_mirrored=(k - 1) // 2,
                                  seed=0, materialize=True)
        lengths = batch.lengths.astype(np.int64)
        keep = np.arange(batch.actions.shape[1])[None, :] < lengths[:, None]
        poses = batch.actions[keep].astype(np.float32)
        state = poses.reshape(-1, 16)
        cols = {"observation.state": state, "action": next_poses(poses, lengths).reshape(-1, 16),
                "frame_index": frame_in_episode(lengths)}

        feats = features()

        def fast():  # one vectorised reduction per distinct episode length
            return episode_stats(cols, feats, lengths)

        def baseline():  # LeRobot's way: statistics episode by episode
            out = {name: {s: [] for s in STAT_KEYS} for name in cols}
            start = 0
            for L in lengths.tolist():
                for name, v in cols.items():
                    v2 = v[start:start + L] if v.ndim == 2 else v[start:start + L, None]
                    for s, val in lerobot_stats(v2[None]).items():
                        out[name][s].append(val[0])
                start += L
            return {name: {s: np.stack(v) for s, v in d.items()} for name, d in out.items()}

        return fast, baseline

    def stats_check(a, b):
        m = len(b["action"]["mean"])  # the baseline may have run on fewer episodes
        for name in b:
            for s in STAT_KEYS:
                np.testing.assert_allclose(a[name][s][:m], b[name][s], rtol=1e-6, atol=1e-9)

    return [BenchCase("exports", "LeRobot per-episode statistics (min/max/mean/std/5 quantiles) of 10k episodes",
                      n + 1 if not quick else n, "episodes", "a Python loop over episodes (LeRobot's own way)",
                      stats_setup, stats_check, repeats=1 if quick else 2, baseline_size=200)]
