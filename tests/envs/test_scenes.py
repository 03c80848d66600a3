"""The scenes an environment resets to (demoforge.envs.scenes): seeded draws under the thesis's and the novel
protocol, as the evaluation draws them."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import demoforge.envs


def test_reset_draws_seeded_scenes_under_the_thesis_and_the_novel_protocols():
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo
    from demoforge.lib.trajectories.query_scenes import augmentation_queries

    task = get_task("trash_in_bin")
    env = gymnasium.make(demoforge.envs.env_id(task.name, "aloha2f140")).unwrapped
    scenes = {}
    for protocol in ("novel", "thesis"):
        a, info = env.reset(seed=5, options={"protocol": protocol})
        b, _ = env.reset(seed=5, options={"protocol": protocol})
        c, _ = env.reset(seed=6, options={"protocol": protocol})
        assert info["protocol"] == protocol
        np.testing.assert_array_equal(a["observation.environment_state"], b["observation.environment_state"])
        assert np.abs(a["observation.environment_state"] - c["observation.environment_state"]).max() > 1e-3
        scenes[protocol] = a["observation.environment_state"]
    # novel: the task library's placement sampler; thesis: the augmentation sampler's held-out stream
    novel = task.keypoints_world(task.sample_placement(np.random.default_rng(5)).object_poses)
    np.testing.assert_allclose(scenes["novel"], novel.reshape(-1), atol=1e-7)
    source = from_scripted_demo(task, task.scripted_demo(0))
    thesis = augmentation_queries(source, 1, int(np.random.default_rng(5).integers(2**31 - 1)))
    np.testing.assert_allclose(scenes["thesis"], thesis.keypoints[0].reshape(-1), atol=1e-7)
    mirrored = {env.reset(seed=s, options={"protocol": "thesis"})[1]["mirrored"] for s in range(8)}
    assert mirrored == {False, True}  # half the thesis's database is mirrored
    with pytest.raises(ValueError, match="unknown protocol"):
        env.reset(options={"protocol": "other"})
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"seed": 1})
    env.close()
