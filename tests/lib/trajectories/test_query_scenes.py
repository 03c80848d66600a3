"""Table 3 grid: query scenes of the two protocols, the knn_blend baseline, and the grid end to end."""

import numpy as np
import pytest

from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.query_scenes import (
    SAME_SCENE_MSE, augmentation_queries, covering_options, nearest_mse, placement_queries,
)


@pytest.fixture(scope="module")
def pouring_db():
    spec = get_task("pouring")
    src = from_scripted_demo(spec, spec.scripted_demo(3))
    return spec, src, generate_episodes(src, n=400, n_mirrored=200, seed=3)


def test_thesis_queries_come_from_the_database_sampler_but_are_never_its_episodes(pouring_db):
    spec, src, db = pouring_db
    q = augmentation_queries(src, 12, seed=3, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert len(q) == 12 and q.keypoints.shape == (12, 11, 3)
    # never a database episode (same seed as the database: the held-out stream still differs)
    d = nearest_mse(q.keypoints, db.keypoints)
    assert np.all(d > SAME_SCENE_MSE) and np.allclose(d, q.nearest_mse)
    # the same distribution: parameters inside the database's box, plain and mirrored layouts both drawn
    lo, hi = db.params[1:].reshape(-1, 3).min(0), db.params[1:].reshape(-1, 3).max(0)
    assert np.all((q.params >= lo - 0.02) & (q.params <= hi + 0.02))
    assert 0 < q.mirrored.sum() < 12
    # its layout's initial grippers: the mirrored scenes start from the mirrored episodes' pose
    mir0 = db.initial[db.kind == "mirrored"][0]
    assert np.allclose(q.initial[q.mirrored], mir0) and np.allclose(q.initial[~q.mirrored], db.initial[0])
    # close to the database in keypoints (the database is dense), but not on it
    assert np.sqrt(d).max() < 0.05
    # deterministic from the seed, different for another seed
    again = augmentation_queries(src, 12, seed=3, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert np.array_equal(again.keypoints, q.keypoints)
    other = augmentation_queries(src, 12, seed=4, database_keypoints=db.keypoints, n_mirrored_fraction=0.5)
    assert not np.allclose(other.keypoints, q.keypoints)


def test_a_query_that_is_a_database_episode_is_skipped(pouring_db):
    spec, src, db = pouring_db
    q = augmentation_queries(src, 3, seed=5, database_keypoints=db.keypoints)
    # a database that happens to contain the first two queries: the sampler must not return them
    db2 = np.concatenate([db.keypoints, q.keypoints[:2]])
    q2 = augmentation_queries(src, 3, seed=5, database_keypoints=db2)
    assert nearest_mse(q2.keypoints, db2).min() > SAME_SCENE_MSE
    assert np.array_equal(q2.keypoints[0], q.keypoints[2])


def test_novel_database_covers_the_placement_sampler(pouring_db):
    spec, src, db = pouring_db
    opts = covering_options(spec, src.keypoints, n_draws=1000)
    assert opts["independent"]
    wide = generate_episodes(src, n=300, n_mirrored=0, seed=0, **opts)
    q = placement_queries(spec, 20, seed=0, initial=db.initial[0], database_keypoints=wide.keypoints)
    # every placement's per-object offset from the demo lies inside the covering ranges
    from demoforge.lib.trajectories.augmentation import estimate_object_poses

    P0 = estimate_object_poses(src.keypoints, spec.keypoints_local, spec.keypoint_object)
    for poses, kp in zip(q.object_poses, q.keypoints):
        for o in range(2):
            d = kp[spec.keypoint_object == o, :2].mean(0) - src.keypoints[spec.keypoint_object == o, :2].mean(0)
            assert opts["translation_range"][0][0] <= d[0] <= opts["translation_range"][0][1]
            assert opts["translation_range"][1][0] <= d[1] <= opts["translation_range"][1][1]
            dyaw = np.angle(np.exp(1j * (np.arctan2(poses[o, 1, 0], poses[o, 0, 0]) - np.arctan2(P0[o, 1, 0], P0[o, 0, 0]))))
            assert opts["yaw_range"][0] <= dyaw <= opts["yaw_range"][1]
    assert not q.mirrored.any() and np.isfinite(q.nearest_mse).all()


def test_knn_blend_of_one_neighbour_carries_it_exactly(pouring_db):
    """An episode carried to its own scene is itself; carried to another episode's scene it is that
    episode (both are the same demo moved by planar transforms), up to the motion blends' rounding."""
    from demoforge.lib.trajectories.augmentation import estimate_object_poses
    from demoforge.lib.trajectories.blend import average_trajectories, knn_blend

    spec, src, db = pouring_db
    a, b = [i for i in np.flatnonzero(db.valid & (db.kind == "translated"))[:2]]
    acts = db.episode_actions([a, b])
    pose_a = estimate_object_poses(db.keypoints[a], spec.keypoints_local, spec.keypoint_object)
    pose_b = estimate_object_poses(db.keypoints[b], spec.keypoints_local, spec.keypoint_object)
    same = knn_blend(src, [(acts[0], db.keypoints[a], False)], pose_a)
    assert np.allclose(same[..., :3], acts[0][..., :3], atol=1e-9)
    moved = knn_blend(src, [(acts[0], db.keypoints[a], False)], pose_b)
    assert np.abs(moved[..., :3] - acts[1][..., :3]).max() < 2e-3
    assert np.array_equal(moved[..., 7], acts[1][..., 7])
    avg = average_trajectories([acts[0], acts[0], acts[1]])
    assert np.allclose(np.linalg.norm(avg[..., 3:7], axis=-1), 1.0)
    assert np.allclose(avg[..., :3], (2 * acts[0][..., :3] + acts[1][..., :3]) / 3)


def test_table3_grid_end_to_end(prefect_api, warehouse, trash_take):
    """One take, two thesis scenes, the LLM-free strategies and a scripted LLM answer: rows for every
    cell, the report views in the thesis's layout, and the nearest episode replayed succeeds."""
    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.flows.table3 import table3
    from demoforge.schemas.catalog import query

    # the command's main path, for the LLM-free strategies: its options reach the flow
    r = CliRunner().invoke(app, ["table3", "--task", "trash_in_bin", "--take-dir", str(trash_take), "--scenes", "2",
                                 "--episodes", "200", "--strategy", "replay_original", "--strategy", "replay_top1",
                                 "--strategy", "knn_blend", "--strategy", "transform_demo"])
    assert r.exit_code == 0, r.output
    assert "Table 3" in r.stdout and "Take1" in r.stdout and "Wilson 95 % intervals" in r.stdout
    db = query("SELECT take, count(*) AS n FROM episodes GROUP BY take", warehouse).to_pylist()
    assert db == [{"take": trash_take.name, "n": 201}]       # the take's database, of --episodes episodes
    # the LLM cells (a scripted answer) beside them: the database comes from the cache
    table3(str(warehouse), task="trash_in_bin", protocols=["thesis"], takes=1, scenes=2, llm_scenes=1,
           strategies=["single", "retrieval"], backend="fake", backend_options={"responses": ["no trajectory here"]},
           episodes=200, take_dirs=[str(trash_take)], show_progress=False)
    rows = query("SELECT * FROM table3_trials ORDER BY strategy, scene", warehouse).to_pylist()
    by = {}
    for r in rows:
        by.setdefault(r["strategy"], []).append(r)
    assert {k: len(v) for k, v in by.items()} == {"single": 1, "retrieval": 1, "replay_original": 2,
                                                   "replay_top1": 2, "knn_blend": 2, "transform_demo": 2}
    # the 3 Retrieved prompt holds the scene's three nearest episodes (those knn_blend blends), and so
    # about three times the one-example prompt
    assert by["retrieval"][0]["example_ids"] == by["knn_blend"][0]["example_ids"]
    assert by["retrieval"][0]["prompt_tokens"] > 2.5 * by["single"][0]["prompt_tokens"]
    assert all(r["protocol"] == "thesis" and r["take_index"] == 1 and r["nearest_mse"] > 0 for r in rows)
    # the scripted LLM answer does not parse: a failed trial, not a crash
    assert by["single"][0]["success"] is False and by["single"][0]["parse_status"] != "ok"
    # the database's nearest episode, replayed, succeeds on an in-distribution scene
    assert any(r["success"] for r in by["replay_top1"]), [r["failure_reason"] for r in by["replay_top1"]]
    for r in by["knn_blend"]:
        assert len(r["example_ids"]) == 3 and r["sim_detail"]
    grid = query("SELECT * FROM report_table3_grid", warehouse).to_pylist()
    assert [g["take"] for g in grid] == ["Take1", "Average"] and grid[0]["one_demo"] == "0/1"
    assert grid[0]["replay_top1"] == f"{sum(r['success'] for r in by['replay_top1'])}/2"
    ci = {r["strategy"]: r for r in query("SELECT * FROM report_table3_intervals", warehouse).to_pylist()}
    for s, r in ci.items():
        assert 0.0 <= r["wilson_low"] <= r["success_rate"] <= r["wilson_high"] <= 1.0
    # a second run is served from the cache: the same rows
    table3(str(warehouse), task="trash_in_bin", protocols=["thesis"], takes=1, scenes=2, llm_scenes=1,
           strategies=["replay_top1"], episodes=200, take_dirs=[str(trash_take)], show_progress=False)
    again = query("SELECT success FROM table3_trials WHERE strategy = 'replay_top1' ORDER BY scene", warehouse)
    assert again.column(0).to_pylist() == [r["success"] for r in by["replay_top1"]]


@pytest.mark.parametrize("args", [["--protocol", "bogus"], ["--strategy", "gpt"], ["--scenes", "2", "--llm-scenes", "3"]])
def test_table3_command_refuses_bad_options_in_one_line(warehouse, args):
    from typer.testing import CliRunner

    from demoforge.cli import app

    r = CliRunner().invoke(app, ["table3", *args])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1, r.output
