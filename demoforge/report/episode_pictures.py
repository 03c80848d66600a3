"""The report's pictures of each task's episode database (demoforge.report: the section "Episode databases in
pictures"): the trajectories, the workspace coverage and one success map per robot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.compute as pc

from demoforge.lib.evaluation.plots import plot_success_map, plot_trajectories, plot_workspace_coverage
from demoforge.lib.task_library import TASK_NAMES, get_task
from demoforge.schemas.catalog import query
from demoforge.schemas.core import column_numpy, read_table, table_files
from demoforge.schemas.reads.episodes import read_steps


def report_plots(warehouse: str, reports_dir: str, tasks: list[str] | None = None, n_augmented: int = 40,
                 coverage_every: int = 3, seed: int = 0) -> list[str]:
    """The three report plots per task with episodes (PNG under ``reports_dir``), as Markdown lines (the
    section's title is its declaration's, in demoforge.schemas.reports)."""
    reports = Path(reports_dir)
    md = []
    have = sorted({f.parent.parent.name.split("=", 1)[1] for f in table_files("episodes", warehouse)})
    tasks = [t for t in (tasks or TASK_NAMES) if t in have]
    if not tasks:
        return ["_No episodes in this warehouse yet: `demoforge augment TAKE`._", ""]
    # one row per episode, whichever runs (a sample, the whole database) checked it
    sim = query("SELECT task, take, episode_id, success, robot, gripper FROM sim_outcomes", warehouse)
    for task in tasks:
        spec = get_task(task)
        take = sorted({f.parent.name.split("=", 1)[1] for f in table_files("episodes", warehouse, task=task)})[0]
        eps = read_table("episodes", warehouse, task=task, take=take)
        ids = eps.column("episode_id").to_numpy()
        valid = eps.column("valid").to_numpy(zero_copy_only=False)
        rng = np.random.default_rng(seed)
        pool = ids[valid & (ids != 0)]
        pick = rng.choice(pool, size=min(n_augmented, len(pool)), replace=False)
        steps = read_steps(warehouse, task, take)
        e, act = episodes_by_id(steps, np.concatenate([[0], pick]))
        kp_all = column_numpy(eps, "object_keypoints")
        kp0 = kp_all[np.flatnonzero(ids == 0)[0]]
        png = plot_trajectories(act[e == 0], [act[e == i] for i in pick], reports / f"trajectories_{task}.png",
                                keypoints=kp0, workspace=spec.workspace,
                                title=f"{task}: the demonstration (bold) and {len(pick)} augmented episodes")
        md += [f"### {task}", "",
               f"Both grippers' paths: the ingested demonstration of `{take}` (bold) and {png['augmented']} "
               "valid augmented episodes drawn at random (thin; translated and mirrored). Translation and yaw act "
               "in the table plane, so the heights over time repeat the demonstration's (a mirrored episode's "
               "left arm follows the demonstration's right arm).", "",
               f"![trajectories {task}](trajectories_{task}.png)", ""]
        e_all, act_all = episodes_by_id(steps, None, every=coverage_every)
        del steps
        cov = plot_workspace_coverage(act_all[:, :, :3], reports / f"coverage_{task}.png", n_episodes=len(ids),
                                      workspace=spec.workspace, title=f"{task}: workspace coverage")
        md += [f"Workspace coverage of all {len(ids):,} episodes (one step in {coverage_every}, 2 cm cells): the "
               f"left gripper visits {100 * cov['covered_fraction']['left']:.0f} % and the right "
               f"{100 * cov['covered_fraction']['right']:.0f} % of the workspace's cells.", "",
               f"![coverage {task}](coverage_{task}.png)", ""]
        rows = sim.filter((pc.field("task") == task) & (pc.field("take") == take))
        if rows.num_rows == 0:
            md += ["_No physics results for this task yet (`demoforge simulate`)._", ""]
            continue
        md += _success_maps(rows, ids, kp_all, spec, task, reports)
    return md


def _success_maps(rows, ids: np.ndarray, kp_all: np.ndarray, spec, task: str, reports: Path) -> list[str]:
    """One success map per robot (the grippers' as success_map_<task>.png, another robot's with its label)."""
    md = []
    robots = rows.column("robot").to_pylist()
    grippers = rows.column("gripper").to_pylist()
    for robot, gripper in sorted(set(zip(robots, grippers)), key=lambda rg: (rg[0] != "grippers", rg)):
        label = robot if robot == "grippers" or gripper == robot else f"{robot}+{gripper}"
        sel = np.array([(r, g) == (robot, gripper) for r, g in zip(robots, grippers)])
        sim_ids = rows.column("episode_id").to_numpy()[sel]
        success = rows.column("success").to_numpy(zero_copy_only=False)[sel]
        order = np.argsort(sim_ids, kind="stable")  # the rows come in file order: draw overlapping markers alike
        sim_ids, success = sim_ids[order], success[order]
        pos = np.argsort(ids)[np.searchsorted(np.sort(ids), sim_ids)]
        kp = kp_all[pos]                                                              # (n, 11, 3)
        obj = spec.keypoint_object
        xy = np.stack([kp[:, obj == o, :2].mean(axis=1) for o in range(len(spec.object_names))], axis=1)
        name = f"success_map_{task}.png" if robot == "grippers" else f"success_map_{task}_{label.replace('+', '_')}.png"
        sm = plot_success_map(xy, success, reports / name, object_names=list(spec.object_names),
                              title=f"{task}: {label} success over object placements")
        md += [f"Success of the {label} robot in MuJoCo over the objects' placements ({sm['episodes']} simulated "
               f"episodes, {100 * sm['success_rate']:.0f} % success; placement = the mean of the object's keypoints "
               "at the episode's start).", "", f"![success map {task} {label}]({name})", ""]
    return md


def episodes_by_id(steps: tuple[np.ndarray, np.ndarray, np.ndarray], ids, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Episode ids and actions (rows, 2, 8) of the given episodes (all when ``ids`` is None), every n-th
    step, from one take's ``read_steps`` (read once per take: it is most of the plots' input time)."""
    e, s, act = steps
    m = np.ones(len(e), bool) if ids is None else np.isin(e, np.asarray(ids))
    if every > 1:
        m &= s % every == 0
    return e[m], act[m].astype(np.float64)
