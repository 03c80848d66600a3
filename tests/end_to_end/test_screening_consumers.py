"""What reads the arms' screening (`episode_screening`): Table 3's database for an arm robot, the sample
`simulate --screened-for` draws, the policy's training set and the joint-space export all keep only the
screened-in episodes (and the original demonstration), and say how to screen when a database is not."""

import json

import numpy as np
import pytest

from demoforge.lib.exports.lerobot import read_lerobot_episode

from tests.support.episodes import TAKE, TASK, build_episode_warehouse

LABEL = "aloha+2f140"


@pytest.fixture(scope="module")
def screened_wh(tmp_path_factory):
    """A pouring database of the seed-1 demonstration (which the arms reach) and a screening that lets every
    other valid episode through."""
    root = tmp_path_factory.mktemp("wh_screened") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root, n=10, n_mirrored=4, demo_seed=1)
    valid = sorted(i for i, v in info["valid"].items() if v)
    return root, info, valid


def _screen(root, ids, executable):
    from demoforge.schemas.core import write_table

    n = len(ids)
    write_table("episode_screening", {
        "task": [TASK] * n, "take": [TAKE] * n, "episode_id": np.asarray(ids, np.int64), "robot": [LABEL] * n,
        "gripper": ["2f140"] * n, "executable": list(executable),
        "reason": ["" if e else "joint_limit" for e in executable], "min_margin_rad": [0.1] * n,
        "turn_left_rad": [0.0] * n, "turn_right_rad": [0.0] * n, "screen_version": ["test"] * n}, root)


def test_an_unscreened_database_says_how_to_screen_it(screened_wh):
    from demoforge.tasks.table3 import _database

    root, _, valid = screened_wh
    assert len(_database(str(root), TASK, TAKE)["ids"]) == len(valid)  # the grippers: every valid episode
    with pytest.raises(ValueError, match="demoforge screen --task pouring --take synth_pouring_s0000 --robot aloha "
                                         "--gripper 2f140"):
        _database(str(root), TASK, TAKE, LABEL)


def test_the_arms_retrieve_sample_learn_and_export_only_screened_in_episodes(screened_wh):
    from demoforge.flows.sim import pick_episodes, selection_name
    from demoforge.tasks.export import export_lerobot
    from demoforge.tasks.policy import load_policy_data
    from demoforge.tasks.table3 import _database

    root, _, valid = screened_wh
    executable = [i % 2 == 1 for i in range(len(valid))]  # episode 0 (the original) screened out: it stays
    _screen(root, valid, executable)
    screened_in = {i for i, e in zip(valid, executable) if e}
    db = _database(str(root), TASK, TAKE, LABEL)
    assert set(db["ids"].tolist()) == screened_in | {0} and (db["kinds"] == "original").sum() == 1
    assert len(db["keypoints"]) == len(db["ids"]) and np.abs(db["keypoints"]).sum(axis=(1, 2)).min() > 0

    ids = pick_episodes(str(root), TASK, TAKE, 3, seed=0, screened_for=LABEL)
    assert ids[0] == 0 and set(ids[1:]) <= screened_in and len(ids) == 3
    assert selection_name(3, ids, 0, LABEL) == "sample-3-seed0-screened-aloha_2f140"

    data, _ = load_policy_data(str(root), TASK, TAKE, n_waypoints=10, robot_label=LABEL)
    assert set(data.episode_id.tolist()) == screened_in | {0}

    out = root.parent / "export"
    s = export_lerobot(str(root), TASK, str(out), robot="aloha", gripper="2f140", unchecked=True)
    meta = json.loads((out / "meta" / "demoforge.json").read_text())
    exported = {int(read_lerobot_episode(out, e)["demoforge.episode_id"][0]) for e in range(s["episodes"])}
    assert "screened in for aloha+2f140" in meta["check"]
    assert exported and exported <= screened_in
    assert len(exported) + s["left_out_unreachable"] == len(screened_in)
