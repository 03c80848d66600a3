"""Benchmark cases for the learned policy (lib/policy): episodes prepared per second and scenes
predicted per second.

prepare  fast     = resample_batch: the waypoint times computed once per group of episodes that share
                    a length and gripper-change steps, the interpolation one vectorised call per group.
         baseline = demoforge.lib.llm.prompting.resample_actions called once per episode (what the prompts use).
predict  fast     = one batched forward pass over all scenes (e.g. evaluating a whole database).
         baseline = one forward pass per scene, as the latency measurement of eval-policy does.
Both on the pouring task's scripted demonstration augmented to `size` episodes; torch on 1 thread.
"""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase


def _batch(n: int):
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
    from demoforge.lib.task_library import get_task

    spec = get_task("pouring")
    return generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=n - 1, n_mirrored=(n - 1) // 2,
                             seed=0, materialize=True)


def _prepare_setup(size: int):
    from demoforge.lib.policy.data import resample_batch
    from demoforge.lib.llm.prompting import resample_actions

    b = _batch(size)
    acts, lengths = b.actions, b.lengths

    def fast():
        return resample_batch(acts, lengths, 20)

    def baseline():
        return np.stack([resample_actions(acts[i, :n], 20) for i, n in enumerate(lengths)])

    return fast, baseline


def _predict_setup(size: int):
    import torch

    from demoforge.lib.policy.data import Normalizer, PolicyData, resample_batch
    from demoforge.lib.policy.model import KeypointPolicy, PolicyConfig

    torch.set_num_threads(1)
    b = _batch(size)
    data = PolicyData(b.episode_id, b.kind, b.params, b.keypoints, b.initial, resample_batch(b.actions, b.lengths, 20))
    torch.manual_seed(0)
    model = KeypointPolicy(PolicyConfig(), Normalizer.fit(data))  # the default architecture; weights don't matter

    def fast():
        return model.predict(data.keypoints, data.initial)

    def baseline():
        return np.stack([model.predict(k, i) for k, i in zip(data.keypoints, data.initial)])

    return fast, baseline


def _same(a, b):
    n = min(len(a), len(b))
    np.testing.assert_allclose(a[:n, ..., :3], b[:n, ..., :3], atol=1e-4)


def cases(quick: bool) -> list[BenchCase]:
    n_prep, n_pred = (500, 256) if quick else (10_001, 2_000)
    return [
        BenchCase("policy", f"resample {n_prep} episodes to 20 waypoints", n_prep, "episodes",
                  "resample_actions once per episode", _prepare_setup, check=_same, repeats=1,
                  baseline_size=None if quick else 2_000),
        BenchCase("policy", f"policy inference, {n_pred} scenes", n_pred, "scenes",
                  "one forward pass per scene", _predict_setup, check=_same, repeats=1,
                  baseline_size=None if quick else 500),
    ]
