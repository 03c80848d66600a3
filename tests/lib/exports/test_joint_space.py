"""The joint-space LeRobot export (demoforge.lib.exports.joint_space): the arms' joint targets reproduce the poses,
and only robot-checked, reachable episodes are kept."""

from __future__ import annotations

import json

import numpy as np
import pytest

from demoforge.lib.exports import ExportError
from tests.support.episodes import TAKE, TASK, build_episode_warehouse


@pytest.fixture(scope="module")
def arm_episode_wh(tmp_path_factory):
    """A pouring database from the seed-1 demonstration, which the ALOHA arms reach (seed 0's they do not),
    with one episode's right hand moved a metre to the right, beyond the arm's reach."""
    from demoforge.schemas.core import column_numpy, read_table, write_table

    root = tmp_path_factory.mktemp("wh_arm_exports") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root, n=4, n_mirrored=2, demo_seed=1)
    far = sorted(i for i, v in info["valid"].items() if v)[-1]
    steps = read_table("episode_steps", root, task=TASK)
    act = column_numpy(steps, "action").copy()
    act[steps.column("episode_id").to_numpy() == far, 1, 0] += 1.0
    write_table("episode_steps", {**{c: steps.column(c) for c in steps.column_names}, "action": act}, root)
    info["actions"][far][:, 1, 0] += 1.0
    return root, {**info, "far": far}


def _sim_rows(ids: list[int], success: list[bool], robot: str = "aloha", gripper: str = "aloha") -> dict:
    n = len(ids)
    return {"task": [TASK] * n, "take": [TAKE] * n, "robot": [robot] * n, "gripper": [gripper] * n,
            "selection": ["ids-test"] * n, "chunk": [0] * n, "episode_id": ids, "kind": ["translated"] * n,
            "success": success, "failure": ["" if s else "unreachable" for s in success], "detail": [""] * n,
            "predicate_ok": [None] * n, "predicate_detail": [""] * n, "reachable": success,
            "ik_position_error_m": [0.001] * n, "ik_rotation_error_deg": [0.1] * n, "time_scale": [1.0] * n,
            "duration_s": [1.0] * n,
            "physics_steps": [480] * n, "wall_s": [0.1] * n}


def test_joint_space_export_reproduces_the_poses_and_keeps_only_checked_reachable_episodes(arm_episode_wh, tmp_path):
    """`export lerobot --robot aloha`: 14 joint values per step named as the ALOHA datasets name them; the
    arms' FK of the exported joints is the path they were planned to follow (the episode's gripper poses as
    the motion retargets them), within 1 cm and 5 degrees as the check, position and orientation, at every
    exported step inside each arm's window; the gripper columns are g; only
    episodes whose arm check passed (all it reaches with --unchecked), never one the IK cannot reach. The
    exported trajectory is what the arms run (their ready-pose start and time-scaling included), at the
    dataset's fps."""
    from scipy.spatial.transform import Rotation

    from demoforge.lib.exports.lerobot import read_lerobot_episode
    from demoforge.lib.sim.robots import get_robot
    from demoforge.lib.sim import SimOptions, planned_execution
    from demoforge.lib.sim.robots.aloha import JOINT_NAMES
    from demoforge.lib.sim.robots.aloha.model import REST
    from demoforge.lib.sim.robots.retiming import at
    from demoforge.schemas.core import write_table
    from demoforge.schemas.reads.episodes import load_episodes
    from demoforge.tasks.export import export_lerobot

    wh, info = arm_episode_wh
    with pytest.raises(ExportError, match="demoforge simulate --task pouring --robot aloha"):
        export_lerobot(str(wh), TASK, str(tmp_path / "none"), robot="aloha")
    s = export_lerobot(str(wh), TASK, str(tmp_path / "all"), robot="aloha", unchecked=True)
    meta = json.loads((tmp_path / "all" / "meta" / "info.json").read_text())
    source = json.loads((tmp_path / "all" / "meta" / "demoforge.json").read_text())
    assert meta["robot_type"] == "aloha" and meta["features"]["observation.state"]["names"] == list(JOINT_NAMES)
    assert meta["features"]["action"]["shape"] == [14] and JOINT_NAMES[:7] == (
        "left_waist", "left_shoulder", "left_elbow", "left_forearm_roll", "left_wrist_angle", "left_wrist_rotate",
        "left_gripper")
    valid = sum(info["valid"].values())
    assert s["episodes"] == valid - 1 and s["left_out_unreachable"] == 1, s
    assert [r[1] for r in source["left_out_unreachable"]] == [info["far"]]
    arms = get_robot("aloha")
    ik = arms.ik(TASK)
    sel = load_episodes(str(wh), TASK)
    assert len(source["time_scale"]) == s["episodes"] and min(source["time_scale"]) > 1.0
    for e in range(s["episodes"]):
        ep = read_lerobot_episode(tmp_path / "all", e)
        i = int(np.flatnonzero(sel.episode_id == int(ep["demoforge.episode_id"][0]))[0])
        poses = info["actions"][int(ep["demoforge.episode_id"][0])]
        # what the arms run: from their ready pose, slowed where a servo is too slow, at the dataset's fps
        motion = planned_execution(TASK, sel.keypoints[i], poses, options=SimOptions(robot=arms)).state
        state = ep["observation.state"].astype(np.float64)
        assert state.shape == (len(motion.q), 14) and len(motion.q) > len(poses)
        assert source["time_scale"][e] == pytest.approx(motion.time_scale, abs=1e-4)
        np.testing.assert_allclose(state[0, [0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]], REST * 2, atol=1e-6)
        np.testing.assert_array_equal(ep["action"][:-1], ep["observation.state"][1:])
        np.testing.assert_allclose(state[:, [6, 13]], np.clip(motion.poses[:, :, 7], 0, 1), atol=1e-6)
        # inside each arm's window, at every exported step, the FK of the exported joints is on the path the
        # arm was planned to follow, position and orientation: the poses the motion records for its windows
        # (ArmMotion.targets: the demonstrated poses as the arms follow them, smoothed, the grasp turned about
        # the held object's symmetry axis), between two demonstrated steps the position interpolated and the
        # rotation slerped, turned half a turn about the pinch frame's z (the gripper's symmetric grasp)
        # where the IK chose that orientation for the window (IKSolution.flipped)
        targets = np.asarray(motion.targets, float)
        assert targets.shape == poses.shape
        fk_pos, fk_R = ik.fk(state[:, [0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]])
        for a in range(2):
            w0, w1 = motion.windows[a]
            rows = np.flatnonzero((motion.s >= w0 - 1e-6) & (motion.s <= w1 - 1 + 1e-6))  # s of repeated retimings
            assert len(rows) >= w1 - 1 - w0 > 0, (e, a, w0, w1)  # (an executed frame moves on by one step at most)
            s_rows = motion.s[rows]
            f0 = np.clip(np.floor(s_rows + 1e-9).astype(int), 0, len(targets) - 2)
            frac = np.clip(s_rows - f0, 0.0, 1.0)
            want_pos = at(targets[:, a, :3], s_rows)
            r0, r1 = Rotation.from_quat(targets[f0, a, 3:7]), Rotation.from_quat(targets[f0 + 1, a, 3:7])
            want_R = r0 * Rotation.from_rotvec(frac[:, None] * (r0.inv() * r1).as_rotvec())
            if motion.ik.flipped[a]:
                want_R = want_R * Rotation.from_euler("z", np.pi)
            pos_err = np.linalg.norm(fk_pos[rows, a] - want_pos, axis=1)
            rot_err = np.degrees((Rotation.from_matrix(fk_R[rows, a]).inv() * want_R).magnitude())
            assert pos_err.max() < 0.01, (e, a, int(rows[np.argmax(pos_err)]), pos_err.max())
            assert rot_err.max() < 5.0, (e, a, int(rows[np.argmax(rot_err)]), rot_err.max())
    exported = [int(read_lerobot_episode(tmp_path / "all", e)["demoforge.episode_id"][0]) for e in range(s["episodes"])]
    dropped = [r[1] for r in source["left_out_unreachable"]]
    # the arm check: only the episodes whose check passed, less any the IK cannot reach
    write_table("sim_results", _sim_rows([exported[0], exported[1], *dropped[:1], 10_000],
                                         [True, False, True, True]), wh)
    c = export_lerobot(str(wh), TASK, str(tmp_path / "checked"), robot="aloha")
    got = [int(read_lerobot_episode(tmp_path / "checked", e)["demoforge.episode_id"][0]) for e in range(c["episodes"])]
    assert got == [exported[0]] and c["left_out_unreachable"] == len(dropped[:1])
