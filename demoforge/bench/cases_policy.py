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
from demoforge.envs.rollout import rollout
from demoforge.lib.llm.prompting import resample_actions
from demoforge.lib.policy.data import Normalizer, PolicyData, resample_batch
from demoforge.lib.policy.joint_demos import joint_demos
from demoforge.lib.sim import SimOptions, execute
from demoforge.lib.sim.robots import get_robot
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes


def _batch(n: int):
    spec = get_task("pouring")
    return generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=n - 1, n_mirrored=(n - 1) // 2,
                             seed=0, materialize=True)


def _prepare_setup(size: int):
    b = _batch(size)
    acts, lengths = b.actions, b.lengths

    def fast():
        return resample_batch(acts, lengths, 20)

    def baseline():
        return np.stack([resample_actions(acts[i, :n], 20) for i, n in enumerate(lengths)])

    return fast, baseline


def _predict_setup(size: int):
    import torch

    from demoforge.lib.policy.model import KeypointPolicy, PolicyConfig  # lazy: torch

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
        *closed_loop_cases(quick),
    ]


# --- the closed-loop policy (lib/policy/chunking.py) ------------------------------------------------------
# train    fast     = train_chunk_policy: the encoder's tokens through an MLP head to the whole chunk.
#          baseline = the same training with ACT's own head: a Transformer decoder of one learned query per
#                     future step (2 layers), as lerobot's ACT has it.
# rollout  fast     = the policy stepping DemoforgeEnv: one forward pass per frame, temporal ensembling, physics.
#          baseline = the robot check's execute() of the demonstration the policy learned (planning and physics,
#                     no inference): what judging one episode costs without a policy in the loop.
# Both on the pouring task's scripted demonstration (seed 1) in the ALOHA arms' joint space; torch on 1 thread.

def _joint_demo():
    from demoforge.envs.robot_env import DemoforgeEnv  # lazy: mujoco

    spec = get_task("pouring")
    src = from_scripted_demo(spec, spec.scripted_demo(1))
    env = DemoforgeEnv("pouring", robot="aloha", gripper="2f140")
    acts = np.asarray(src.trajectory, np.float64)
    demos = joint_demos(get_robot("aloha", "2f140"), spec, acts, np.array([len(acts)]), src.keypoints[None])
    return env, demos, src, acts


def _decoder_policy(config):
    """A ChunkPolicy whose head is ACT's query decoder (the baseline architecture)."""
    import torch
    from torch import nn

    from demoforge.lib.policy.chunking import ChunkPolicy  # lazy: mujoco, torch

    class DecoderPolicy(ChunkPolicy):
        def __init__(self, c):
            super().__init__(c)
            layer = nn.TransformerDecoderLayer(c.d_model, c.n_heads, c.ff_dim, dropout=0.0, batch_first=True,
                                               norm_first=True)
            self.decoder = nn.TransformerDecoder(layer, 2)
            self.queries = nn.Parameter(torch.randn(c.chunk, c.d_model) * 0.02)
            self.out = nn.Linear(c.d_model, c.state_dim)

        def forward(self, state, time_s, keypoints, pinch=None):
            memory = self.encode(state, time_s, keypoints, pinch)
            return self.out(self.decoder(self.queries.expand(len(state), -1, -1), memory))

    return DecoderPolicy(config)


def _train_setup(size: int):
    import torch

    # lazy: mujoco, torch
    from demoforge.lib.policy.chunk_train import ChunkTrainConfig, train_chunk_policy
    from demoforge.lib.policy.chunking import ChunkConfig

    torch.set_num_threads(1)
    _, demos, _, _ = _joint_demo()
    cfg = ChunkTrainConfig(steps=size)

    def fast():
        return np.array(train_chunk_policy(demos, train=cfg).losses)

    def baseline():
        return np.array(train_chunk_policy(demos, train=cfg, model=_decoder_policy(ChunkConfig())).losses)

    return fast, baseline


def _rollout_setup(size: int):
    import torch

    # lazy: mujoco, torch
    from demoforge.lib.policy.chunk_train import ChunkTrainConfig, train_chunk_policy
    from demoforge.lib.policy.chunking import TemporalEnsemble

    torch.set_num_threads(1)
    env, demos, src, acts = _joint_demo()
    ensemble = TemporalEnsemble(train_chunk_policy(demos, train=ChunkTrainConfig(steps=50)).model)
    states = demos.states
    frames = len(states) - 1
    options = SimOptions(robot=env.robot)

    class Timed:
        """The policy's inference at every frame, the demonstration's action: a whole episode's physics, whatever
        the (briefly trained) weights would do."""

        def reset(self):
            ensemble.reset()

        def __call__(self, state, environment_state, time_s):
            ensemble(state, environment_state, time_s)
            return states[min(int(round(time_s * 30)) + 1, frames)]

    def fast():
        return np.array([rollout(env, Timed(), options={"state": states[0], "keypoints": src.keypoints,
                                                        "max_steps": frames})["frames"] for _ in range(size)])

    def baseline():
        return np.array([execute("pouring", src.keypoints, acts, options=options).n_frames for _ in range(size)])

    return fast, baseline


def _finite(a, b):
    assert np.isfinite(a).all() and np.isfinite(b).all()


def closed_loop_cases(quick: bool) -> list[BenchCase]:
    steps, episodes = (50, 1) if quick else (1000, 3)
    return [
        BenchCase("policy", f"closed-loop policy training, {steps} steps of 256 frames", steps, "steps",
                  "ACT's query decoder as the head", _train_setup, check=_finite, repeats=1,
                  baseline_size=None if quick else 200),
        BenchCase("policy", f"closed-loop rollout in the environment, {episodes} episode(s)", episodes, "episodes",
                  "execute() of the demonstration (no policy)", _rollout_setup, check=_finite, repeats=1),
    ]
