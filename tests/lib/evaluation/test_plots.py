"""The report plots: each writes a real PNG and returns the numbers it drew, checked against inputs
designed so the answer is known; report_plots runs on a warehouse of real augmented episodes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.evaluation.plots import (
    coverage_grid, plot_success_map, plot_trajectories, plot_workspace_coverage,
)


def _png(path) -> np.ndarray:
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 400
    return img


def _poses(T: int, offset=(0.0, 0.0)) -> np.ndarray:
    p = np.zeros((T, 2, 8))
    t = np.linspace(0, 1, T)
    p[:, 0, :3] = np.stack([-0.2 + 0.1 * t + offset[0], 0.1 + 0.2 * t + offset[1], 0.1 + 0.1 * t], 1)
    p[:, 1, :3] = p[:, 0, :3] * [-1, 1, 1]
    p[..., 6] = 1.0
    p[..., 7] = 1.0
    return p


def test_trajectory_plot_draws_the_demo_and_the_episodes(tmp_path):
    out = tmp_path / "traj.png"
    r = plot_trajectories(_poses(50), [_poses(50, (0.05 * k, 0.02)) for k in range(4)], out,
                          keypoints=np.zeros((11, 3)), workspace=np.array([[-0.45, -0.2, 0], [0.45, 0.6, 0.65]]),
                          title="t")
    assert r == {"augmented": 4, "steps": 50}
    img = _png(out)
    assert img[..., :3].std() > 0.05  # not a blank canvas
    with pytest.raises(ValueError, match=r"\(steps, 2, 8\)"):
        plot_trajectories(np.zeros((5, 8)), [], tmp_path / "bad.png")
    assert not (tmp_path / "bad.png").exists()


@settings(max_examples=60, deadline=None)
@given(st.sets(st.tuples(st.integers(0, 9), st.integers(0, 4)), min_size=1, max_size=50), st.integers(1, 4))
def test_coverage_counts_exactly_the_visited_cells(cells, reps):
    """Samples placed in the centres of chosen 2 cm cells of a 20 x 10 cm workspace: the left arm
    fills exactly those cells with ``reps`` samples each, the right arm (always in one cell) one."""
    cells = np.array(sorted(cells))
    ws = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.5]])
    p = np.zeros((len(cells) * reps, 2, 3))
    p[:, 0, :2] = np.repeat((cells + 0.5) * 0.02, reps, axis=0)
    p[:, 1, :2] = [0.01, 0.01]
    h, ex, ey = coverage_grid(p, ws, cell=0.02)
    assert h.shape == (2, 10, 5)
    assert np.allclose(ex, np.linspace(0, 0.2, 11)) and np.allclose(ey, np.linspace(0, 0.1, 6))
    want = np.zeros((10, 5))
    want[cells[:, 0], cells[:, 1]] = reps
    np.testing.assert_array_equal(h[0], want)
    assert h[1].sum() == len(p) and h[1][0, 0] == len(p)


def test_coverage_plot_reports_the_covered_fraction(tmp_path):
    p = np.zeros((40, 2, 3))
    p[:20, :, 0] = 0.01   # cell (0, 0) for both arms ...
    p[20:, :, 0] = 0.05   # ... and cell (2, 0)
    p[:, 1, 1] = 0.03     # the right arm one row up
    p[0, 0] = np.nan      # dropped
    r = plot_workspace_coverage(p, tmp_path / "cov.png", workspace=np.array([[0, 0, 0], [0.2, 0.1, 1]]),
                                n_episodes=2)
    assert r["covered_fraction"] == {"left": pytest.approx(2 / 50), "right": pytest.approx(2 / 50)}
    assert r["samples"] == 39
    _png(tmp_path / "cov.png")


def test_success_map_rates_per_cell(tmp_path):
    """Two cells of the bottle's placement: 3 of 4 and 0 of 2 successes."""
    xy = np.zeros((6, 2, 2))
    xy[:4, 0] = [0.05, 0.05]
    xy[4:, 0] = [0.15, 0.15]
    xy[:, 1] = [[0.1, 0.1]] * 6
    success = np.array([True, True, True, False, False, False])
    r = plot_success_map(xy, success, tmp_path / "sm.png", object_names=["bottle", "cup"],
                         region=np.array([[0.0, 0.0], [0.2, 0.2]]), bins=2)
    rate = r["cell_rates"]["bottle"]
    assert rate[0, 0] == pytest.approx(0.75) and rate[1, 1] == 0.0
    assert np.isnan(rate[0, 1]) and np.isnan(rate[1, 0])  # no episode there
    assert r["success_rate"] == pytest.approx(0.5)
    _png(tmp_path / "sm.png")
    with pytest.raises(ValueError, match="simulate"):
        plot_success_map(np.zeros((0, 2, 2)), np.zeros(0, bool), tmp_path / "none.png")


def test_report_plots_on_real_episodes(tmp_path):
    """The report's section from a warehouse with real augmented episodes and physics results."""
    from demoforge.report.episode_pictures import report_plots
    from demoforge.schemas.core import write_table
    from tests.support.episodes import TAKE, TASK, build_episode_warehouse

    wh = tmp_path / "warehouse"
    wh.mkdir()
    info = build_episode_warehouse(wh, n=8, n_mirrored=4)
    reports = tmp_path / "reports"
    md = report_plots(str(wh), str(reports), n_augmented=5)
    text = "\n".join(md)
    assert f"![trajectories {TASK}](trajectories_{TASK}.png)" in text
    assert "No physics results" in text and not (reports / f"success_map_{TASK}.png").exists()
    ids = sorted(info["actions"])[:5]
    ok = [True, False, True, False, False]
    write_table("sim_results", {
        "task": [TASK] * 5, "take": [TAKE] * 5, "robot": ["grippers"] * 5, "gripper": ["2f140"] * 5,
        "reachable": [None] * 5, "ik_position_error_m": [None] * 5, "ik_rotation_error_deg": [None] * 5, "time_scale": [None] * 5,
        "selection": ["sample-5-seed0"] * 5, "chunk": np.zeros(5, np.int32), "episode_id": np.array(ids, np.int64),
        "kind": [info["kind"][i] for i in ids], "success": ok, "failure": ["" if s else "missed_grasp" for s in ok],
        "detail": [""] * 5, "predicate_ok": ok, "predicate_detail": [""] * 5, "duration_s": np.ones(5),
        "physics_steps": np.ones(5, np.int64), "wall_s": np.ones(5)}, wh)
    md = report_plots(str(wh), str(reports), n_augmented=5)
    text = "\n".join(md)
    assert "grippers robot in MuJoCo over the objects' placements (5 simulated episodes, 40 % success" in text
    for name in ("trajectories", "coverage", "success_map"):
        _png(reports / f"{name}_{TASK}.png")
    arms_ok = [True, True, True, False, False]  # the arms' own map beside the grippers' (not one pooled map)
    write_table("sim_results", {
        "task": [TASK] * 5, "take": [TAKE] * 5, "robot": ["aloha"] * 5, "gripper": ["2f140"] * 5,
        "reachable": [True] * 5, "ik_position_error_m": [0.001] * 5, "ik_rotation_error_deg": [0.1] * 5,
        "time_scale": [1.1] * 5, "selection": ["sample-5-seed0"] * 5, "chunk": np.zeros(5, np.int32),
        "episode_id": np.array(ids, np.int64), "kind": [info["kind"][i] for i in ids], "success": arms_ok,
        "failure": ["" if s else "joint_limit" for s in arms_ok], "detail": [""] * 5, "predicate_ok": arms_ok,
        "predicate_detail": [""] * 5, "duration_s": np.ones(5), "physics_steps": np.ones(5, np.int64),
        "wall_s": np.ones(5)}, wh)
    text = "\n".join(report_plots(str(wh), str(reports), n_augmented=5))
    assert "grippers robot in MuJoCo over the objects' placements (5 simulated episodes, 40 % success" in text
    assert "aloha+2f140 robot in MuJoCo over the objects' placements (5 simulated episodes, 60 % success" in text
    _png(reports / f"success_map_{TASK}_aloha_2f140.png")
    n_eps = len(info["actions"])
    assert f"all {n_eps:,} episodes" in text


def test_data_scaling_plot_draws_one_panel_per_task_with_the_baselines(tmp_path):
    import cv2

    from demoforge.lib.evaluation.data_scaling import plot_data_scaling

    def row(task, method, n, k, lo, hi):
        return {"task": task, "robot": "aloha+2f140", "method": method, "n_train_episodes": n, "scenes": 50,
                "successes": k, "success_rate": k / 50, "wilson_low": lo, "wilson_high": hi}

    rows = [row("pouring", "closed_loop", 1, 0, 0.0, 0.07), row("pouring", "closed_loop", 100, 20, 0.28, 0.54),
            row("pouring", "replay_top1", 6000, 43, 0.74, 0.93), row("trash_in_bin", "closed_loop", 10, 9, 0.1, 0.31)]
    one = plot_data_scaling(rows[:3], tmp_path / "one.png")
    two = plot_data_scaling(rows, tmp_path / "two.png")
    w1, w2 = cv2.imread(str(one)).shape[1], cv2.imread(str(two)).shape[1]
    assert w2 > 1.6 * w1                                      # a second task, a second panel
    assert plot_data_scaling([rows[2]], tmp_path / "none.png") is None and not (tmp_path / "none.png").exists()
