"""The closed-loop policy (issue 43): its training data are the environment's own observations of the episodes
the arms execute, it learns them, its chunks are ensembled as ACT does, a bad action ends a rollout as a recorded
failure. (The data-scaling flow: tests/flows/test_closed_loop.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.envs.observation import ENV_STATE, STATE
from demoforge.lib.policy.chunk_train import ChunkTrainConfig, frame_times, targets_index, train_chunk_policy
from demoforge.lib.policy.chunking import TemporalEnsemble
from demoforge.lib.policy.joint_demos import GRIPPER_COLUMNS, JointDemos, commanded_grippers, joint_demos
from tests.support.episodes import TASK, build_episode_warehouse


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The seed-1 pouring demonstration (the arms reach it) and a mirrored episode, in the arms' joint space."""
    from demoforge.envs.robot_env import DemoforgeEnv
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task
    from demoforge.schemas.reads.episodes import load_episodes

    root = tmp_path_factory.mktemp("closed_loop") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root, n=4, n_mirrored=2, demo_seed=1)
    mirrored = min(i for i, k in info["kind"].items() if k == "mirrored" and info["valid"][i])
    sel = load_episodes(str(root), TASK, only={("synth_pouring_s0000", 0), ("synth_pouring_s0000", mirrored)})
    env = DemoforgeEnv(TASK, robot="aloha", gripper="2f140")
    demos = joint_demos(get_robot("aloha", "2f140"), get_task(TASK), sel.poses, sel.lengths, sel.keypoints)
    return env, demos, sel


def test_the_training_frames_are_what_the_environment_shows_and_replaying_them_succeeds(demo):
    env, demos, sel = demo
    assert demos.keep.all() and len(demos) == 2
    states, environment = demos.episode(0)
    actions = states[1:]  # the gripper columns are already the commands the robot check issues
    obs, info = env.reset(options={"state": states[0], "keypoints": sel.keypoints[0], "max_steps": len(actions)})
    assert np.allclose(obs[ENV_STATE], environment[0], atol=1e-5)
    worst_kp = 0.0
    for t, a in enumerate(actions):
        obs, reward, terminated, truncated, info = env.step(a)
        assert np.allclose(obs[STATE], states[t + 1], atol=1e-6)
        worst_kp = max(worst_kp, float(np.abs(obs[ENV_STATE] - environment[t + 1]).max()))
        if terminated or truncated:
            break
    assert worst_kp < 1e-3, worst_kp          # the held objects' keypoints: within a millimetre
    assert info["success"], info["detail"]
    g = states[:, list(GRIPPER_COLUMNS)]
    assert ((g < 0.5).sum(0) > 0).all() and set(np.unique(g)) <= {0.0, 1.0}  # both hands close, commands are 0/1


def test_commanded_grippers_close_early_in_each_episode_only():
    s = np.ones((10, 14))
    s[6:, 6] = 0.0     # episode 0 (frames 0-4) stays open; episode 1 closes the left hand at its frame 1
    out = commanded_grippers(s, np.array([5, 5]), lead=3)
    assert out[:5, 6].tolist() == [1, 1, 1, 1, 1]          # no close leaks back into the previous episode
    assert out[5:, 6].tolist() == [0, 0, 0, 0, 0] and (out[:, 13] == 1).all()
    assert np.array_equal(out[:, :6], s[:, :6])


def test_targets_are_the_next_frames_of_the_same_episode_held_at_its_end():
    idx = targets_index(np.array([3, 2]), chunk=4)
    assert idx.tolist() == [[1, 2, 2, 2], [2, 2, 2, 2], [2, 2, 2, 2], [4, 4, 4, 4], [4, 4, 4, 4]]
    assert np.allclose(frame_times(np.array([3, 2]), 30.0), [0, 1 / 30, 2 / 30, 0, 1 / 30])


def test_training_fits_the_demonstration_reproducibly_and_checkpoints_round_trip(demo, tmp_path):
    from demoforge.lib.policy.chunk_train import chunk_checkpoint_id, load_chunk_checkpoint, save_chunk_checkpoint

    _, demos, _ = demo
    cfg = ChunkTrainConfig(steps=120, batch_size=64, warmup_steps=10)
    a = train_chunk_policy(demos, train=cfg, seed=3)
    b = train_chunk_policy(demos, train=cfg, seed=3)
    assert a.losses[-1] < 0.5 * a.losses[0], a.losses
    assert chunk_checkpoint_id(a.model) == chunk_checkpoint_id(b.model)
    assert chunk_checkpoint_id(train_chunk_policy(demos, train=cfg, seed=4).model) != chunk_checkpoint_id(a.model)
    states, environment = demos.episode(0)
    chunk = a.model.predict(states[40], environment[40], 40 / 30)
    assert chunk.shape == (a.model.config.chunk, 14) and np.isfinite(chunk).all()
    assert ((chunk[:, list(GRIPPER_COLUMNS)] >= 0) & (chunk[:, list(GRIPPER_COLUMNS)] <= 1)).all()
    save_chunk_checkpoint(a.model, tmp_path / "ck", {"note": "test"})
    again = load_chunk_checkpoint(tmp_path / "ck")
    assert np.array_equal(again.predict(states[40], environment[40], 40 / 30), chunk)
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(Exception):
        load_chunk_checkpoint(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError, match="train-policy --closed-loop"):
        load_chunk_checkpoint(tmp_path / "nothing")
    with pytest.raises(ValueError, match="no episodes"):
        train_chunk_policy(JointDemos(np.zeros((0, 14), np.float32), np.zeros((0, 33), np.float32),
                                      np.zeros(0, np.int64), np.zeros(0, bool), "aloha+2f140", TASK), train=cfg)


class _Counting:
    """A policy stand-in whose chunk predicted at step s holds 100 s + k at its k-th step."""

    def predict(self, state, environment_state, time_s):
        s = int(round(time_s * 30))
        return np.repeat((100.0 * s + np.arange(5))[:, None], 14, axis=1)


def test_temporal_ensembling_weights_the_oldest_chunk_most():
    ens = TemporalEnsemble(_Counting(), decay=0.5)
    outs = [ens(None, None, t / 30)[0] for t in range(7)]
    w = np.exp(-0.5 * np.arange(3))
    assert outs[0] == 0.0
    assert np.isclose(outs[2], (w * [2.0, 101.0, 200.0]).sum() / w.sum())   # chunks of steps 0, 1, 2 for step 2
    w5 = np.exp(-0.5 * np.arange(5))
    assert np.isclose(outs[6], (w5 * [204.0, 303.0, 402.0, 501.0, 600.0]).sum() / w5.sum())  # only 5 overlap
    ens.reset()
    assert ens(None, None, 0.0)[0] == 0.0


def test_a_policy_answering_nan_or_the_wrong_shape_ends_the_rollout_not_the_loop(demo):
    from demoforge.envs.rollout import rollout

    env, _, sel = demo
    out = rollout(env, lambda s, e, t: np.full(14, np.nan), options={"keypoints": sel.keypoints[0]})
    assert (out["success"], out["failure"], out["frames"]) == (False, "invalid_action", 0)
    with pytest.raises(ValueError, match="shape"):
        rollout(env, lambda s, e, t: np.zeros(7), options={"keypoints": sel.keypoints[0]})
    # and the environment goes on: a policy holding the ready pose runs to its step limit
    still = rollout(env, lambda s, e, t: s, options={"keypoints": sel.keypoints[0], "max_steps": 20})
    assert still["frames"] == 20 and not still["success"] and still["failure"]
