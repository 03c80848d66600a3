"""The simulate flow (demoforge.flows.sim) on the augmented episodes of one full synthetic take, through Prefect:
it resumes by chunk, renders, and keeps a sample's and a whole run's results apart."""

from pathlib import Path

import pytest

from demoforge.flows.augment import augment_take_flow
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.schemas.catalog import query


@pytest.fixture()
def take_dir(trash_take):
    return trash_take


def test_simulate_flow_resumes_by_chunk_and_renders(prefect_api, ingested_warehouse, take_dir, tmp_path, monkeypatch):
    warehouse = ingested_warehouse  # the take ingested once per session
    from demoforge.flows.sim import render_episode_video, simulate_episodes

    augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=40, n_mirrored=20, seed=2), show_progress=False)
    first = simulate_episodes(str(warehouse), task="trash_in_bin", episodes=4, chunk_size=2, show_progress=False)
    assert [m.rows for m in first] == [2, 2]
    rows = query("SELECT * FROM sim_results ORDER BY episode_id", warehouse).to_pylist()
    assert rows[0]["episode_id"] == 0 and rows[0]["kind"] == "original"
    # the take's own demonstration, mapped to the grippers, passes the robot check
    assert rows[0]["success"] and rows[0]["failure"] == "", rows[0]["detail"]
    from demoforge.lib.sim import FAILURES

    assert all((r["success"] and r["failure"] == "") or (not r["success"] and r["failure"] in FAILURES) for r in rows)
    assert all(r["physics_steps"] > 0 for r in rows)

    # a crash lost chunk 1: only that chunk is simulated again
    Path(first[1].files[0]).unlink()
    calls = []
    import demoforge.lib.sim as rs

    real = rs.execute_many
    monkeypatch.setattr(rs, "execute_many", lambda task, eps, **kw: calls.append(len(eps)) or real(task, eps, **kw))
    again = simulate_episodes(str(warehouse), task="trash_in_bin", episodes=4, chunk_size=2, show_progress=False)
    assert calls == [2] and again[0] == first[0]

    row = render_episode_video(str(warehouse), "trash_in_bin", 0, tmp_path / "ep0.mp4")
    assert (tmp_path / "ep0.mp4").stat().st_size > 10_000 and row["success"] == rows[0]["success"]

    # the ALOHA arms on the same sample: their own rows (robot, gripper, the IK residual) beside the
    # grippers', which stay as they were; sim_outcomes keeps one row per episode and robot
    arms = simulate_episodes(str(warehouse), task="trash_in_bin", episodes=4, chunk_size=4, show_progress=False,
                             robot="aloha", gripper="2f140")
    assert [m.rows for m in arms] == [4] and "robot=aloha/gripper=2f140/" in arms[0].files[0]
    assert all(m.is_intact() for m in again)
    got = query("SELECT robot, gripper, episode_id, reachable, ik_position_error_m, failure FROM sim_outcomes "
                "ORDER BY robot, episode_id", warehouse).to_pylist()
    assert [(r["robot"], r["episode_id"]) for r in got] == [("aloha", r["episode_id"]) for r in rows] + [
        ("grippers", r["episode_id"]) for r in rows]
    for r in got:
        arm = r["robot"] == "aloha"
        assert (r["reachable"] is not None) == arm and (r["ik_position_error_m"] is not None) == arm
        assert r["reachable"] is not True or r["failure"] not in ("unreachable", "joint_limit")


def test_sample_and_whole_runs_keep_their_own_results_and_new_episodes_are_simulated_again(
        prefect_api, ingested_warehouse, take_dir, monkeypatch):
    warehouse = ingested_warehouse  # the take ingested once per session
    from demoforge.flows.sim import simulate_episodes
    import demoforge.lib.sim as rs
    from demoforge.schemas.core import column_numpy, read_table, write_table

    augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=40, n_mirrored=20, seed=2), show_progress=False)
    sample = simulate_episodes(str(warehouse), task="trash_in_bin", episodes=3, chunk_size=2, show_progress=False)
    sample_ids = [r["episode_id"] for r in query("SELECT episode_id FROM sim_results ORDER BY 1", warehouse).to_pylist()]
    valid = [r["episode_id"] for r in query("SELECT episode_id FROM episodes WHERE valid ORDER BY 1", warehouse).to_pylist()]
    # a second run over other episodes (sharing the original) used to write the same chunk files
    other = [0] + [e for e in valid if e not in sample_ids][:2]
    simulate_episodes(str(warehouse), task="trash_in_bin", episodes=other, chunk_size=2, show_progress=False)
    assert all(m.is_intact() for m in sample), "the second run overwrote the sample's files"
    per_run = query("SELECT selection, count(*) AS n FROM sim_results GROUP BY 1 ORDER BY 1", warehouse).to_pylist()
    assert [r["n"] for r in per_run] == [3, 3] and per_run[1]["selection"] == "sample-3-seed0"
    assert per_run[0]["selection"].startswith("ids-")
    outcomes = query("SELECT episode_id FROM sim_outcomes ORDER BY 1", warehouse).to_pylist()
    assert [r["episode_id"] for r in outcomes] == sorted(set(sample_ids) | set(other))  # episode 0 once

    # the same episode ids with other content (a re-augmented take): simulated again, not served from
    # the cache. Here the actions are lifted 2 m, so every episode must now fail.
    steps = read_table("episode_steps", warehouse, task="trash_in_bin")
    lifted = column_numpy(steps, "action").copy()
    lifted[:, :, 2] += 2.0
    write_table("episode_steps", {**{c: steps.column(c) for c in steps.column_names}, "action": lifted}, warehouse)
    calls = []
    real = rs.execute_many
    monkeypatch.setattr(rs, "execute_many", lambda task, eps, **kw: calls.append(len(eps)) or real(task, eps, **kw))
    simulate_episodes(str(warehouse), task="trash_in_bin", episodes=3, chunk_size=2, show_progress=False)
    assert calls == [2, 1]
    again = query("SELECT success, failure FROM sim_results WHERE selection = 'sample-3-seed0'", warehouse).to_pylist()
    assert len(again) == 3 and not any(r["success"] for r in again)
