"""Flows: execute a task's episodes with a robot (lib/sim/robots: the floating grippers or the ALOHA arms)
in MuJoCo; check how stable the outcomes are under a rigid sub-millimetre shift of the scene; render one
episode as a video."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Sequence

import numpy as np
from prefect import flow, get_run_logger

from demoforge.lib.robot_spec import RobotSpec
from demoforge.lib.sim import scene_fingerprint, sim_options
from demoforge.lib.sim.render import render_episode
from demoforge.lib.sim.stability import scene_offsets
from demoforge.lib.task_library import TASK_NAMES
from demoforge.runtime.artifacts import ProgressArtifact
from demoforge.schemas.catalog import query
from demoforge.schemas.core import table_files
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.tasks.common import Manifest, in_distributed_flow, run_stage, run_stages
from demoforge.tasks.screening import screened_ids
from demoforge.tasks.sim import simulate_chunk, stability_chunk


def pick_episodes(warehouse: str, task: str, take: str, episodes: int | str | Sequence[int], seed: int = 0,
                  screened_for: str | None = None) -> list[int]:
    """`all` valid episodes, N of them (the original first, then a seeded random sample), or the given ids;
    screened_for (an arm robot's label, `aloha+2f140`): of the valid episodes only those its screening lets
    through (`episode_screening`; `demoforge screen`), and the original."""
    t = query("SELECT episode_id FROM episodes WHERE task = ? AND take = ? AND valid "
              "ORDER BY episode_id", warehouse, [task, take])
    valid = np.asarray(t.column(0).to_numpy())
    if screened_for is not None:
        valid = valid[np.isin(valid, screened_ids(warehouse, task, take, screened_for)) | (valid == 0)]
    if isinstance(episodes, str):
        if episodes != "all":
            raise ValueError(f"episodes must be a number, a list of ids or 'all', got {episodes!r}")
        return valid.tolist()
    if isinstance(episodes, (int, np.integer)):
        n = min(int(episodes), len(valid))
        rest = np.random.default_rng(seed).permutation(valid[valid != 0])
        return ([0] if 0 in valid else []) + sorted(rest[: n - (1 if 0 in valid else 0)].tolist())
    return [int(e) for e in episodes]


def selection_name(episodes: int | str | Sequence[int], ids: Sequence[int], seed: int,
                   screened_for: str | None = None) -> str:
    """The `sim_results` selection of a run: `all`, `sample-N-seedS`, or `ids-<hash of the ids>` (with
    `-screened-<robot>` when drawn from a screening's episodes). Runs of different selections write separate
    files, so a sample never overwrites a whole-database run."""
    tail = f"-screened-{screened_for.replace('+', '_')}" if screened_for else ""  # a partition value: no +
    if isinstance(episodes, str):
        return "all" + tail
    if isinstance(episodes, (int, np.integer)):
        return f"sample-{len(ids)}-seed{int(seed)}{tail}"
    digest = hashlib.sha256(",".join(str(int(i)) for i in ids).encode()).hexdigest()[:12]
    return f"ids-{digest}"


def stability_run_name(selection: str, repeats: int, jitter_m: float, seed: int) -> str:
    """The `sim_stability` run: the episode selection plus repeats, jitter and seed, e.g.
    `sample-40-seed0-r5-j0.0001-s0`: runs with other settings keep their own files."""
    return f"{selection}-r{int(repeats)}-j{float(jitter_m):g}-s{int(seed)}"


def _episode_database(warehouse: str, task: str, take: str | None) -> tuple[str, list]:
    """The take whose episodes to check (default: the task's first) and its files (for cache keys)."""
    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    # (query() also brings files of older table contracts to the current layout before anything is written)
    takes = query("SELECT DISTINCT take FROM episodes WHERE task = ? ORDER BY take", warehouse, [task]).column(0).to_pylist()
    if take is None and takes:
        take = takes[0]
    if take not in takes:
        raise ValueError(f"no episode database for {task!r}{' from take ' + take if take else ''}: run `demoforge augment` first")
    source = [*table_files("episodes", warehouse, task=task, take=take),
              *table_files("episode_steps", warehouse, task=task, take=take)]
    return take, source


def _robot_args(task: str, spec: RobotSpec) -> dict:
    """The chunk stages' robot arguments (strings, as their cache keys have them) with the scene fingerprint."""
    return {"robot": spec.robot, "gripper": spec.gripper, "scene": scene_fingerprint(task, sim_options(spec))}


@flow(name="simulate-episodes")
def simulate_episodes(warehouse: str, task: str = "pouring", episodes: int | str | list[int] = "all",
                      take: str | None = None, chunk_size: int = 100, workers: int = 2, seed: int = 0,
                      show_progress: bool = True, robot: RobotSpec | str = "grippers", gripper: str | None = None,
                      screened_for: str | None = None) -> list[Manifest]:
    """Execute episodes of a task's database in MuJoCo with `robot` (a RobotSpec, its label, or a robot's
    name with hand `gripper`, default its own; an unknown one: RobotError) (results: `sim_results`), chunk by chunk; screened_for: draw them from the episodes that arm robot's
    screening lets through (pick_episodes), the same episodes for every robot.

    Each chunk is one cached stage: a run that crashed resumes where it stopped, and a re-run with
    the same episodes costs nothing. Its rows carry the run's selection (selection_name) and the robot:
    a sample and a whole-database run of the same task, or two robots, keep their own files."""
    spec = RobotSpec.of(robot, gripper)
    if screened_for is not None:
        screened_for = RobotSpec.parse(screened_for).label
    robot_args = _robot_args(task, spec)
    take, source = _episode_database(warehouse, task, take)
    ids = pick_episodes(warehouse, task, take, episodes, seed, screened_for)
    selection = selection_name(episodes, ids, seed, screened_for)
    common = dict(task=task, take=take, selection=selection, warehouse=warehouse, source=source,
                  workers=workers, show_progress=show_progress, **robot_args)
    return _run_chunks(simulate_chunk, warehouse, common, ids, chunk_size, f"{task}: {selection} ({spec.label})",
                       artifact=(f"simulate-{task}", f"{task}: chunks of {chunk_size} episodes executed in MuJoCo"))


def _run_chunks(stage, warehouse: str, common: dict, ids: list[int], chunk_size: int, desc: str,
                artifact: tuple[str, str] | None = None) -> list[Manifest]:
    """Run a chunked stage over `ids` (one cached call per chunk of chunk_size episodes). On a Dask
    cluster the chunks run in parallel, one per worker process; here one after the other under the
    whole run's progress bar, and with a Prefect progress artifact (key, description) if given."""
    calls = [dict(common, chunk=k, episode_ids=ids[i:i + chunk_size])
             for k, i in enumerate(range(0, len(ids), chunk_size))]
    if in_distributed_flow():
        for c in calls:
            c.update(workers=1, show_progress=False)
        return run_stages(stage, warehouse, calls)

    progress = ProgressArtifact(artifact[0], len(calls), artifact[1]) if artifact else None
    logger = get_run_logger()
    out = []
    with _run_bar(desc, len(ids), common["show_progress"]) as bar:
        for k, call in enumerate(calls):
            out.append(run_stage(stage, warehouse, **call))
            if progress is not None:
                progress.step()
            bar.update(len(call["episode_ids"]))
            logger.info("%s: chunk %d/%d done", desc, k + 1, len(calls))
    return out


def _run_bar(desc: str, total: int, show: bool):
    """The whole run's progress bar (episodes, with the rate and the time left), above each chunk's own;
    chunks served from the cache advance it at once."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="episode", position=0, disable=not show, smoothing=0.05)


@flow(name="check-stability")
def check_stability(warehouse: str, task: str = "pouring", episodes: int | str | list[int] = 40, repeats: int = 5,
                    jitter_m: float = 1e-4, take: str | None = None, chunk_size: int = 20, workers: int = 2,
                    seed: int = 0, show_progress: bool = True, robot: RobotSpec | str = "grippers",
                    gripper: str | None = None) -> list[Manifest]:
    """Execute each selected episode `repeats` times, the scene shifted rigidly along the table by
    `jitter_m` (standard deviation, metres) in every repeat but the first; rows in `sim_stability`, the
    summary in the `report_sim_stability` view. Chunks are cached stages, like simulate_episodes."""
    scene_offsets([0], repeats, jitter_m)  # bad repeats / jitter: fail before any work, with the reason
    spec = RobotSpec.of(robot, gripper)
    robot_args = _robot_args(task, spec)
    take, source = _episode_database(warehouse, task, take)
    ids = pick_episodes(warehouse, task, take, episodes, seed)
    run = stability_run_name(selection_name(episodes, ids, seed), repeats, jitter_m, seed)
    common = dict(task=task, take=take, run=run, repeats=int(repeats), jitter_m=float(jitter_m), seed=int(seed),
                  warehouse=warehouse, source=source, workers=workers, show_progress=show_progress, **robot_args)
    return _run_chunks(stability_chunk, warehouse, common, ids, chunk_size, f"{task}: stability {run} ({spec.label})")


def render_episode_video(warehouse: str, task: str, episode_id: int, out: str | Path, take: str | None = None,
                         robot: RobotSpec | str = "grippers", gripper: str | None = None) -> dict:
    """An offscreen MP4 of the robot executing one episode; returns the simulation's summary row."""
    from dataclasses import replace

    opt = replace(sim_options(RobotSpec.of(robot, gripper)), stop_on_hard_failure=False)  # the whole episode, past a failure

    t = query("SELECT take, object_keypoints FROM episodes WHERE task = ? AND episode_id = ? "
              "AND (? IS NULL OR take = ?) ORDER BY take LIMIT 1", warehouse, [task, int(episode_id), take, take])
    if t.num_rows == 0:
        raise ValueError(f"no episode {episode_id} of task {task!r} in the warehouse")
    take = t.column("take")[0].as_py()
    kp = np.asarray(t.column("object_keypoints")[0].as_py(), float)
    actions = episode_actions(warehouse, task, take, [episode_id])[int(episode_id)]
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    return render_episode(task, kp, actions, str(out), options=opt).row()
