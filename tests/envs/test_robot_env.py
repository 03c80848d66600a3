"""The Gymnasium environment (demoforge.envs.robot_env): every task with each robot, whose observations and actions
are the joint-space export's features, and whose physics and verdict are the robot check's. (Registration:
test_envs.py; the scenes it resets to: test_scenes.py.)

The episodes are real: each task's scripted demonstration (seed 1), its first scripted fault and its
mirrored variant, written into a warehouse with the tables' contracts and exported to LeRobot in joint
space (`export_lerobot(..., robot="aloha", gripper="2f140", unchecked=True)`)."""

from __future__ import annotations

import json
import warnings

import gymnasium
import numpy as np
import pytest

import demoforge.envs
from demoforge.envs.observation import ENV_STATE, STATE
from demoforge.lib.task_library import TASK_NAMES

TAKES = ("a_demo", "b_fault", "c_mirror")  # the demonstration, its first fault, its mirror image
SEED = 1  # the scripted demonstration, and its mirror image, that the arms execute in every task


def _step_through(env, actions):
    """Step the actions until the episode ends: (observations, the last step's reward, terminated, truncated, info)."""
    obs = []
    for a in actions:
        o, reward, terminated, truncated, info = env.step(a)
        obs.append(o)
        if terminated or truncated:
            break
    return obs, reward, terminated, truncated, info


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """{task: (export folder, EpisodeSelection as exported)}: three episodes per task, their joint-space export."""
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
    from demoforge.schemas.core import write_table
    from demoforge.tasks.augment import episode_steps_columns, episodes_columns
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.tasks.export import export_lerobot

    root = tmp_path_factory.mktemp("envs")
    wh = root / "warehouse"
    wh.mkdir()
    out = {}
    for name in TASK_NAMES:
        task = get_task(name)
        for take, fault, mirror in zip(TAKES, (None, task.faults[0], None), (False, False, True)):
            batch = generate_episodes(from_scripted_demo(task, task.scripted_demo(SEED, mirror=mirror, fault=fault)),
                                      n=0, n_mirrored=0, seed=1, workers=1)
            write_table("episodes", episodes_columns(name, take, 1, batch), wh)
            write_table("episode_steps", episode_steps_columns(name, take, batch), wh)
        summary = export_lerobot(str(wh), name, str(root / name), robot="aloha", gripper="2f140", unchecked=True)
        assert summary["episodes"] == len(TAKES) and summary["left_out_unreachable"] == 0, summary
        out[name] = (root / name, load_episodes(str(wh), name))
    return out


def _episode(exported, task: str, e: int):
    """(the export's rows of episode e, its keypoints, its demonstrated (n, 2, 8) poses as the warehouse keeps them)."""
    from demoforge.lib.exports.lerobot import read_lerobot_episode

    folder, sel = exported[task]
    ep = read_lerobot_episode(folder, e)
    assert ep["demoforge.take"][0] == sel.take[e]
    start = int(np.sum(sel.lengths[:e]))
    return ep, sel.keypoints[e], sel.poses[start:start + sel.lengths[e]].astype(np.float64)


# ------------------------------------------------------------------------------------------ the checker

@pytest.mark.parametrize("key", ["aloha", "aloha2f140", "grippers"])
def test_gymnasium_env_checker_passes(key):
    from gymnasium.utils.env_checker import check_env

    camera = {"width": 64, "height": 48, "K": [[57.0, 0, 31.5], [0, 57.0, 23.5], [0, 0, 1]]}
    env = gymnasium.make(demoforge.envs.env_id("paper_in_case", key), images=True, camera=camera,
                         render_mode="rgb_array", max_steps=15).unwrapped
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized.*")  # the export's units, not [-1, 1]
        check_env(env)
    obs, _ = env.reset(seed=0)
    image = obs[f"observation.images.{'top' if key != 'grippers' else 'camera'}"]  # the export's video keys
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8 and image.std() > 5
    np.testing.assert_array_equal(env.render(), image)
    env.close()


# ------------------------------------------------------------------------------------------ the export's rows

@pytest.mark.parametrize("task", TASK_NAMES)
def test_the_observation_of_an_exported_step_is_the_exports_row(exported, task):
    """Reset to an exported episode's scene and first row, step through its `action` column: every observation
    is the export's row of that step (names, shapes, dtypes, values: the state exactly, the object keypoints
    to float32 precision), the plain and the mirrored demonstration alike."""
    env = gymnasium.make(demoforge.envs.env_id(task, "aloha2f140")).unwrapped
    meta = json.loads((exported[task][0] / "meta" / "info.json").read_text())
    assert {name: meta["features"][name] for name in env.features} == env.features  # names, shapes, dtypes
    assert meta["fps"] == env.fps == env.metadata["render_fps"] == 30
    assert env.observation_space[STATE].shape == env.action_space.shape == (14,)
    assert env.observation_space[ENV_STATE].shape == (33,)
    for e in (0, 2):
        ep, keypoints, _ = _episode(exported, task, e)
        state, env_state = ep["observation.state"], ep["observation.environment_state"]
        obs, info = env.reset(options={"keypoints": keypoints, "state": state[0], "max_steps": len(state) - 1})
        observed = [obs] + _step_through(env, ep["action"])[0]
        assert len(observed) == len(state)
        for k, o in enumerate(observed):
            assert set(o) == {"observation.state", "observation.environment_state"}
            assert all(v.dtype == np.float32 for v in o.values())
            np.testing.assert_array_equal(o["observation.state"], state[k])
            np.testing.assert_allclose(o["observation.environment_state"], env_state[k], rtol=0, atol=2e-7)
    env.close()


@pytest.mark.parametrize("task", TASK_NAMES)
def test_an_exported_episode_replayed_in_the_env_gets_its_robot_check_verdict(exported, task):
    """The robot check of each episode (execute with the options of `demoforge simulate --robot aloha --gripper
    2f140`: its sim_results row) and the environment replaying the exported joint rows get the same verdict:
    success, or the same failure class (the scripted faults fail their predicate)."""
    from demoforge.lib.sim import execute
    from demoforge.lib.sim.failures import FAILURES
    from demoforge.lib.sim import sim_options

    env = gymnasium.make(demoforge.envs.env_id(task, "aloha2f140")).unwrapped
    verdicts = []
    for e in range(len(TAKES)):
        ep, keypoints, poses = _episode(exported, task, e)
        check = execute(task, keypoints, poses, options=sim_options("aloha", "2f140"))
        first, actions = env.replay_actions(ep["observation.state"])
        env.reset(options={"keypoints": keypoints, "state": first, "max_steps": len(actions)})
        obs, reward, terminated, truncated, info = _step_through(env, actions)
        assert (info["success"], info["failure"]) == (check.success, check.failure), (e, info["detail"], check.detail)
        assert reward == (1.0 if check.success else 0.0) and (terminated, truncated) == (check.success, not check.success)
        assert info["failure"] is None or info["failure"] in FAILURES
        assert info["result"]["n_frames"] == check.n_frames == len(ep["observation.state"])
        verdicts.append(check.failure)
    assert verdicts == [None, "predicate_not_met", None]
    env.close()


@pytest.mark.parametrize("task, fault, robot, gripper, failure", [
    ("pouring", None, "aloha", "aloha", "wider_than_stroke"),  # ALOHA's fingers do not open around the bottle
    ("mix_bowl", "no_circle", "aloha", "aloha", "object_dropped"),
    ("open_container", None, "grippers", "2f140", None),
])
def test_the_env_runs_the_physics_of_execute_bit_for_bit(task, fault, robot, gripper, failure):
    """Driven with the frames execute plans (the arms' joints in float64, the grippers' poses), with the close
    commands execute issues, the environment's simulation is execute's: the same SimResult, every recorded
    object and gripper pose equal to the last bit, the early stop at a hard failure included."""
    from demoforge.lib.sim import SimOptions, execute, planned_execution
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.task_library import get_task

    key = {"aloha": "aloha", "2f140": "aloha2f140"}[gripper] if robot == "aloha" else "grippers"
    demo = get_task(task).scripted_demo(1, fault=fault)
    keypoints, actions = demo.keypoints()[0], demo.gripper_actions()
    options = SimOptions(robot=get_robot(robot, gripper))
    check = execute(task, keypoints, actions, options=options)
    if robot == "aloha":
        states = options.robot.joint_values(planned_execution(task, keypoints, actions, options=options))
    else:
        states = actions.reshape(len(actions), 16)
    env = gymnasium.make(demoforge.envs.env_id(task, key)).unwrapped
    first, commands = env.replay_actions(states)
    env.reset(options={"keypoints": keypoints, "state": first, "max_steps": len(commands)})
    _step_through(env, commands)
    mine = env.stepper.finish()
    assert check.failure == failure and (mine.success, mine.failure, mine.detail) == (check.success, check.failure, check.detail)
    assert (mine.predicate_ok, mine.predicate_detail, mine.physics_steps) == (check.predicate_ok, check.predicate_detail,
                                                                             check.physics_steps)
    np.testing.assert_array_equal(mine.object_poses, check.object_poses)
    np.testing.assert_array_equal(mine.gripper_poses, check.gripper_poses)
    np.testing.assert_array_equal(mine.touch, check.touch)
    env.close()


def test_the_rendered_image_is_the_exports_video_frame():
    """observation.images.top of a step is the frame the export's video draws for it (episode_frames from the
    same camera, before the video's encoding), pixel for pixel (the first second: software rendering is slow)."""
    from itertools import islice

    from demoforge.lib.sim import SimOptions, planned_execution
    from demoforge.lib.sim.render import episode_frames
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.synth.render import camera_K, camera_T_world_camera
    from demoforge.lib.task_library import get_task

    demo = get_task("paper_in_case").scripted_demo(1)
    keypoints, actions = demo.keypoints()[0], demo.gripper_actions()
    options = SimOptions(robot=get_robot("aloha", "2f140"))
    K = np.diag([0.1, 0.1, 1.0]) @ camera_K()  # 64 x 48 of the synthetic head camera
    frames = 31
    video = list(islice(episode_frames("paper_in_case", keypoints, actions, K, camera_T_world_camera(), 64, 48,
                                       options=SimOptions(robot=options.robot, stop_on_hard_failure=False)), frames))
    env = gymnasium.make("demoforge/paper_in_case-aloha2f140-v0", images=True,
                         camera={"K": K, "width": 64, "height": 48}).unwrapped
    first, commands = env.replay_actions(options.robot.joint_values(planned_execution("paper_in_case", keypoints,
                                                                                      actions, options=options)))
    obs, _ = env.reset(options={"keypoints": keypoints, "state": first, "max_steps": frames - 1})
    images = [obs["observation.images.top"]] + [o["observation.images.top"] for o in _step_through(env, commands)[0]]
    assert len(images) == len(video) == frames
    for k, (mine, theirs) in enumerate(zip(images, video)):
        np.testing.assert_array_equal(mine, theirs, err_msg=f"frame {k}")
    assert np.abs(images[-1].astype(int) - images[0]).max() > 50  # the arms moved in between
    env.close()


def test_the_close_commands_are_the_executors():
    from demoforge.lib.sim import SimOptions
    from demoforge.lib.sim.executor import _schedule
    from demoforge.lib.sim.gripper import GripperSpec
    from demoforge.lib.sim.stepper import close_commands
    from demoforge.lib.task_library import get_task

    actions = get_task("empty_vase").scripted_demo(1).gripper_actions()
    spec = GripperSpec()
    sch = _schedule(actions, 30.0, SimOptions(), spec, 1.0 / 480.0)
    lead = round(spec.close_lead_s * 30)
    np.testing.assert_array_equal(close_commands(actions[..., 7], lead), sch.closed_cmd)
    assert (close_commands(actions[..., 7], lead) != (actions[..., 7] < 0.5)).sum() == 2 * lead


# ------------------------------------------------------------------------------------------ early success

def test_success_ends_the_episode_early_when_checked_every_k_steps(exported):
    """check_success_every: the predicate on the state of every k-th step; when it holds, the settle phase and
    the verdict at once (reward 1 there, terminated)."""
    ep, keypoints, _ = _episode(exported, "trash_in_bin", 0)
    env = gymnasium.make("demoforge/trash_in_bin-aloha2f140-v0", check_success_every=15).unwrapped
    first, actions = env.replay_actions(ep["observation.state"])
    env.reset(options={"keypoints": keypoints, "state": first, "max_steps": len(actions)})
    obs, reward, terminated, truncated, info = _step_through(env, actions)
    assert (reward, terminated, truncated, info["success"]) == (1.0, True, False, True)
    assert info["frame"] % 15 == 0 and info["frame"] < len(actions)
    env.close()


# ------------------------------------------------------------------------------------------ bad input

def test_bad_actions_give_a_clear_error_or_a_recorded_failure_never_a_crash():
    env = gymnasium.make("demoforge/mix_bowl-aloha2f140-v0", max_steps=40).unwrapped
    obs, _ = env.reset(seed=1)
    hold = obs["observation.state"]
    for bad in (hold[:7], np.zeros((2, 7)), "fourteen", [hold, hold]):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    obs, reward, terminated, truncated, info = env.step(hold)  # the episode goes on after a refused action
    assert info["frame"] == 1 and not (terminated or truncated)
    far = hold.copy()
    far[0], far[6] = 10.0, 1.7  # a waist far beyond its range, g above 1: clipped to the action space
    obs, reward, terminated, truncated, info = env.step(far)
    assert info["action_clipped"] and obs["observation.state"][0] == env.action_space.high[0]
    assert obs["observation.state"][6] == 1.0 and env.observation_space.contains(obs)
    assert not env.step(hold)[-1]["action_clipped"]
    nan = hold.copy()
    nan[3] = np.nan
    obs, reward, terminated, truncated, info = env.step(nan)
    assert (reward, terminated, truncated) == (0.0, True, False)
    assert (info["success"], info["failure"]) == (False, "invalid_action") and "left_forearm_roll" in info["detail"]
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(hold)
    # a rollout loop on random and broken actions: every episode ends with a verdict, nothing raises
    rng = np.random.default_rng(0)
    for episode in range(3):
        env.reset(seed=episode)
        done = False
        while not done:
            a = env.action_space.sample() if rng.random() < 0.9 else np.full(14, np.inf)
            obs, reward, terminated, truncated, info = env.step(a)
            done = terminated or truncated
        assert info["success"] is not None and (info["failure"] is None) == info["success"]
    grippers = gymnasium.make("demoforge/mix_bowl-grippers-v0").unwrapped
    obs, _ = grippers.reset(seed=1)
    zero = obs["observation.state"].copy()
    zero[3:7] = 0.0
    assert grippers.step(zero)[-1]["failure"] == "invalid_action"
    with pytest.raises(ValueError, match="keypoints|object poses"):
        grippers.reset(options={"object_poses": np.zeros((3, 3))})
    env.close()
    grippers.close()
