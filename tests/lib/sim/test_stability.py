"""Outcome stability of the robot check: rigid micrometre shifts of the scene, the flow and its table."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from typer.testing import CliRunner

from demoforge.lib.sim.stability import scene_offsets, shift_scene, stability_summary
from demoforge.lib.trajectories.augmentation.options import AugmentOptions

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_steps=st.integers(1, 12), offset=st.tuples(finite, finite, finite))
def test_shift_scene_moves_everything_rigidly_and_nothing_else(seed, n_steps, offset):
    rng = np.random.default_rng(seed)
    kp = rng.uniform(-0.5, 0.5, (11, 3))
    q = rng.normal(size=(n_steps, 2, 4))
    actions = np.concatenate([rng.uniform(-0.5, 0.5, (n_steps, 2, 3)), q / np.linalg.norm(q, axis=-1, keepdims=True),
                              rng.integers(0, 2, (n_steps, 2, 1)).astype(float)], axis=-1)
    kp0, a0 = kp.copy(), actions.copy()
    kp2, a2 = shift_scene(kp, actions, offset)
    np.testing.assert_array_equal(kp, kp0)  # inputs untouched
    np.testing.assert_array_equal(actions, a0)
    # every distance between keypoints and gripper positions is kept: the scene moved as one body
    pts, pts2 = np.concatenate([kp, actions[..., :3].reshape(-1, 3)]), np.concatenate([kp2, a2[..., :3].reshape(-1, 3)])
    np.testing.assert_allclose(pts2 - pts2[:1], pts - pts[:1], atol=1e-12)
    np.testing.assert_allclose(pts2 - pts, np.broadcast_to(offset, pts.shape), atol=1e-12)
    np.testing.assert_array_equal(a2[..., 3:], actions[..., 3:])  # orientations and gripper states


def test_shift_scene_rejects_a_malformed_offset():
    with pytest.raises(ValueError, match=r"offset must have shape \(3,\)"):
        shift_scene(np.zeros((11, 3)), np.zeros((4, 2, 8)), [0.1, 0.2])


def test_offsets_leave_repeat_zero_alone_keep_objects_on_the_table_and_depend_only_on_the_episode():
    off = scene_offsets([0, 5, 9], repeats=4, jitter_m=1e-4, seed=3)
    assert off.shape == (3, 4, 3)
    assert not off[:, 0].any() and not off[..., 2].any()
    assert np.all(np.abs(off[:, 1:, :2]) > 0)
    # the same episode gets the same shifts whatever else the run checks, in whatever order
    np.testing.assert_array_equal(scene_offsets([9, 5], 4, 1e-4, seed=3), off[[2, 1]])
    assert not np.array_equal(scene_offsets([5], 4, 1e-4, seed=4), off[[1]])
    big = scene_offsets(np.arange(2000), 2, 1e-4)[:, 1, :2]
    assert big.std() == pytest.approx(1e-4, rel=0.05) and abs(big.mean()) < 1e-5


@pytest.mark.parametrize("repeats, jitter, message", [(1, 1e-4, "repeats must be at least 2"),
                                                      (3, 0.0, "jitter_m must be a positive"),
                                                      (3, float("nan"), "jitter_m must be a positive")])
def test_offsets_reject_settings_that_check_nothing(repeats, jitter, message):
    with pytest.raises(ValueError, match=message):
        scene_offsets([0], repeats, jitter)


def test_stability_summary_counts_flipping_episodes():
    s = np.array([[1, 1, 1], [0, 0, 0], [1, 0, 1], [0, 1, 0]], bool)
    out = stability_summary(s)
    assert out == {"episodes": 4, "repeats": 3, "first_run_success_rate": 0.5, "success_rate": 0.5,
                   "always": 1, "never": 1, "flipping": 2}
    with pytest.raises(ValueError):
        stability_summary(np.ones(3, bool))


def test_a_shifted_scripted_demo_still_succeeds():
    """Physics is translation-invariant: the scripted demonstration, shifted by 0.1 mm, is still a success
    (a stable episode: the grasp and the placement have margins far above the shift)."""
    from demoforge.lib.sim import execute
    from demoforge.lib.task_library import get_task

    demo = get_task("trash_in_bin").scripted_demo(0, False)
    kp, actions = demo.keypoints()[0], demo.gripper_actions()
    for offset in scene_offsets([0], 3, 1e-4)[0]:
        r = execute("trash_in_bin", *shift_scene(kp, actions, offset))
        assert r.success, (offset, r.failure, r.detail)


def test_stability_flow_repeats_each_episode_and_its_unshifted_run_matches_simulate(
        prefect_api, ingested_warehouse, trash_take, monkeypatch):
    warehouse = ingested_warehouse  # the take ingested once per session
    from demoforge.flows.augment import augment_take_flow
    from demoforge.cli import app
    from demoforge.flows.sim import check_stability, simulate_episodes
    import demoforge.lib.sim as rs
    from demoforge.schemas.catalog import query

    from demoforge.schemas.core import read_table_file, table_files

    augment_take_flow(str(trash_take), str(warehouse), augment=AugmentOptions(n=40, n_mirrored=20, seed=2), show_progress=False)
    simulate_episodes(str(warehouse), task="trash_in_bin", episodes=3, chunk_size=3, show_progress=False)
    # the command's main path: its options reach the flow (episodes, repeats, jitter, chunk size)
    out = CliRunner().invoke(app, ["stability", "--task", "trash_in_bin", "--episodes", "3", "--repeats", "2",
                                   "--jitter", "0.0001", "--chunk-size", "2"])
    assert out.exit_code == 0, out.output
    assert sorted(read_table_file("sim_stability", f).num_rows for f in table_files("sim_stability", warehouse)) == [2, 4]
    rows = query("SELECT * FROM sim_stability ORDER BY episode_id, repeat", warehouse).to_pylist()
    assert {r["run"] for r in rows} == {"sample-3-seed0-r2-j0.0001-s0"}
    assert [r["repeat"] for r in rows] == [0, 1] * 3
    assert all(r["offset_x"] == r["offset_y"] == 0.0 for r in rows if r["repeat"] == 0)
    assert all(0 < abs(r["offset_x"]) < 1e-3 for r in rows if r["repeat"] == 1)
    # repeat 0 is exactly the robot check `simulate` made of the same episodes
    sim = {r["episode_id"]: r for r in query("SELECT * FROM sim_results", warehouse).to_pylist()}
    assert sorted(sim) == sorted({r["episode_id"] for r in rows})
    for r in rows:
        if r["repeat"] == 0:
            s = sim[r["episode_id"]]
            assert (r["success"], r["failure"], r["detail"]) == (s["success"], s["failure"], s["detail"])
    summary = query("SELECT * FROM report_sim_stability", warehouse).to_pylist()
    assert len(summary) == 1 and summary[0]["episodes"] == 3 and summary[0]["repeats"] == 2
    assert "1 rows" in out.stdout  # the command prints that summary (report_sim_stability of the task)
    expected = stability_summary(np.array([r["success"] for r in rows]).reshape(3, 2))  # rows: by episode, repeat
    assert summary[0]["always_succeed"] == expected["always"]
    assert summary[0]["never_succeed"] == expected["never"]
    assert summary[0]["flipping"] == expected["flipping"]

    # cached: the same run executes nothing again
    calls = []
    real = rs.execute_many
    monkeypatch.setattr(rs, "execute_many", lambda task, eps, **kw: calls.append(len(eps)) or real(task, eps, **kw))
    check_stability(str(warehouse), task="trash_in_bin", episodes=3, repeats=2, jitter_m=1e-4, chunk_size=2,
                    show_progress=False)
    assert calls == []

    # the same run in other chunks: older chunk files hold the same rows again, each counted once
    check_stability(str(warehouse), task="trash_in_bin", episodes=3, repeats=2, jitter_m=1e-4, chunk_size=3,
                    show_progress=False)
    again = query("SELECT * FROM report_sim_stability", warehouse).to_pylist()
    assert again == summary

    # the CLI explains bad settings instead of running
    r = CliRunner().invoke(app, ["stability", "--task", "trash_in_bin", "--episodes", "3", "--jitter", "0"])
    assert r.exit_code == 2 and "jitter_m must be a positive number of metres" in r.output
