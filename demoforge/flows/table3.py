"""Flow: the thesis's Table 3 grid -- takes x query scenes x strategies, under a named protocol."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.flows.augment import augment_take_flow
from demoforge.flows.ingest import ingest_take
from demoforge.flows.policy import train_policy
from demoforge.flows.screening import screen_task
from demoforge.lib.robot_spec import RobotSpec
from demoforge.lib.sim import scene_fingerprint, sim_options
from demoforge.lib.takes import open_take
from demoforge.lib.task_library import TASK_NAMES, get_task
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.lib.trajectories.query_scenes import PROTOCOLS, augmentation_queries, covering_options, placement_queries
from demoforge.runtime.runners import run_flow
from demoforge.schemas.core import column_numpy, read_table
from demoforge.schemas.reads.demonstration import demo_arrays, load_demo_source
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.llm_eval import keyframe_key
from demoforge.tasks.table3 import ALL_STRATEGIES, LLM_STRATEGIES, POLICY, table3_trials

NOVEL_SUFFIX = "_novel"  # database key of a take's `novel` database: <take>_novel (episodes.take)


def database_name(take_id: str, protocol: str) -> str:
    """The key of a take's database for a protocol: the take itself for `thesis` (the database
    `make evaluate` builds), <take>_novel for `novel` (another augmentation of the same take)."""
    return take_id if protocol == "thesis" else take_id + NOVEL_SUFFIX


@flow(name="table3")
def table3(
    warehouse: str,
    task: str = "pouring",
    protocols: Sequence[str] = ("thesis",),
    takes: int = 5,
    scenes: int = 10,
    llm_scenes: int | None = None,
    strategies: Sequence[str] = ALL_STRATEGIES,
    backend: str = "local",
    backend_options: dict | None = None,
    seed: int = 0,
    episodes: int = 10_000,
    policy_epochs: int = 6,
    policy_waypoints: int = 40,
    policy_threads: int = 2,
    n_waypoints: int | None = None,
    precision: int = 3,
    max_tokens: int | None = None,
    structured: bool | None = None,
    number_format: str | None = None,
    take_dirs: Sequence[str] | None = None,
    show_progress: bool = True,
    robot: RobotSpec | str = "grippers",
    gripper: str | None = None,
) -> list[Manifest]:
    """For each of `takes` synthetic takes of `task` (seeds seed, seed+1, ...; or the given take_dirs)
    and each protocol: the take's episode database (`episodes` episodes), `scenes` query scenes, and
    every strategy judged on them in MuJoCo (the LLM prompts on the first `llm_scenes`, default all).

    thesis: the database of `make evaluate` (both objects translated together, half mirrored) and scenes
    from its own sampler with held-out seeds. novel: the task library's placements (objects placed and
    turned independently) against a second database of the take built to cover them (independent
    objects, translation and yaw ranges spanning the placement sampler, no mirrored episodes).
    Every cell is cached (LLM answers too): an interrupted grid resumes where it stopped. `robot`
    (a RobotSpec, its label, or a robot's name with hand `gripper`): the robot that executes every prediction
    (lib/sim/robots; default the floating grippers).
    """
    from tqdm import tqdm

    from demoforge.flows.synth import synthesize_takes  # lazy: mujoco

    logger = get_run_logger()
    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    bad = [p for p in protocols if p not in PROTOCOLS]
    if bad or not protocols:
        raise ValueError(f"unknown protocol {bad}; choose from {', '.join(PROTOCOLS)}")
    bad = [s for s in strategies if s not in ALL_STRATEGIES]
    if bad or not strategies:
        raise ValueError(f"unknown strategy {bad}; choose from {', '.join(ALL_STRATEGIES)}")
    if takes < 1 or scenes < 1 or episodes < 10:
        raise ValueError(f"need takes >= 1, scenes >= 1 and episodes >= 10, got {takes}, {scenes}, {episodes}")
    llm_scenes = scenes if llm_scenes is None else int(llm_scenes)
    if not 0 <= llm_scenes <= scenes:
        raise ValueError(f"llm_scenes must be between 0 and scenes ({scenes}), got {llm_scenes}")
    if take_dirs:
        paths = [str(Path(p).resolve()) for p in take_dirs][:takes]
    else:
        paths = [m.path for m in run_flow(synthesize_takes, warehouse, tasks=[task], takes=takes, seed=seed,
                                          mirror="no", show_progress=show_progress)]
    spec = get_task(task)
    arm = RobotSpec.of(robot, gripper)  # an unknown robot or hand: RobotError, before any work
    opt = sim_options(arm)
    judge = {} if arm.robot == "grippers" else {  # the grippers' cells keep their cache keys
        "robot": arm.robot, "gripper": arm.gripper, "scene_key": scene_fingerprint(task, opt)}
    cells = [s for s in strategies if s not in LLM_STRATEGIES or llm_scenes > 0]
    out: list[Manifest] = []
    bar = tqdm(total=len(paths) * len(protocols) * len(cells), desc=f"table3 {task}", unit="cell",
               disable=None if show_progress else True)
    try:
        for i, path in enumerate(paths, start=1):
            for protocol in protocols:
                db, q, ck = _prepare(warehouse, spec, path, protocol, scenes, seed, episodes,
                                     POLICY in strategies, policy_epochs, policy_waypoints, policy_threads, show_progress)
                if judge:  # an arm robot retrieves from (and learns from) the episodes its screening lets through
                    judge["screening"] = run_flow(screen_task, warehouse, task=task, take=db["database"], robot=arm.robot,
                                                  gripper=arm.gripper)
                    if ck is not None:
                        ck = run_flow(train_policy, warehouse, task=task, take=db["database"], seed=seed,
                                      epochs=policy_epochs, max_minutes=None, threads=policy_threads,
                                      n_waypoints=policy_waypoints, robot_label=arm.label,
                                      screening=judge["screening"])
                for strategy in cells:
                    bar.set_postfix_str(f"{protocol} take {i} {strategy}")
                    llm = strategy in LLM_STRATEGIES
                    n = llm_scenes if llm else scenes
                    m = run_stage(table3_trials, warehouse, task=task, protocol=protocol, take=db["take"], take_index=i,
                                  database=db["database"], strategy=strategy, warehouse=warehouse,
                                  episodes=db["episodes"], scenes=[q.scene(j) for j in range(n)], seed=seed,
                                  backend=backend if llm else "none", backend_options=(backend_options or {}) if llm else {},
                                  n_waypoints=n_waypoints, precision=precision, max_tokens=max_tokens if llm else None,
                                  structured=structured if llm else None,
                                  number_format=number_format if llm else None,
                                  keyframes=keyframe_key(task, n_waypoints) if llm else None,
                                  policy_checkpoint=ck if strategy == POLICY else None, show_progress=show_progress,
                                  **judge)
                    logger.info("%s %s take %d (%s) %s: %d trials", task, protocol, i, db["take"], strategy, m.rows)
                    out.append(m)
                    bar.update(1)
    finally:
        bar.close()
    return out


def _prepare(warehouse: str, spec, path: str, protocol: str, scenes: int, seed: int, episodes: int, policy: bool,
             policy_epochs: int, policy_waypoints: int, policy_threads: int, show_progress: bool):
    """The take's database for the protocol (built or from the cache), its query scenes, and the
    policy trained on it (None unless asked)."""
    take_id = open_take(path).take_id
    name = database_name(take_id, protocol)
    if protocol == "thesis":  # exactly the database `make evaluate` builds from its first take
        options, n_mirrored = {}, episodes // 2
    else:
        run_flow(ingest_take, path, warehouse, show_progress=show_progress)
        options, n_mirrored = covering_options(spec, demo_arrays(take_id, spec.name, warehouse)[1], seed=seed), 0
    aug = run_flow(augment_take_flow, path, warehouse,
                   augment=AugmentOptions(n=episodes, n_mirrored=n_mirrored, seed=seed, generation=options),
                   database=None if name == take_id else name, show_progress=show_progress)
    ep = read_table("episodes", warehouse, task=spec.name, take=name).sort_by("episode_id")
    kp_all = column_numpy(ep, "object_keypoints")  # every episode, valid or not: none may be a query
    if protocol == "thesis":
        q = augmentation_queries(load_demo_source(take_id, spec.name, warehouse), scenes, seed, kp_all,
                                 n_mirrored_fraction=n_mirrored / episodes, **options)
    else:
        kinds = ep.column("kind").to_pylist()
        init = column_numpy(ep, "initial_poses")[kinds.index("original")]
        q = placement_queries(spec, scenes, seed, init, kp_all)
    ck = None
    if policy:
        # no time cap: a run that stops on a budget is not reproducible from its seed
        ck = run_flow(train_policy, warehouse, task=spec.name, take=name, seed=seed, epochs=policy_epochs,
                      max_minutes=None, threads=policy_threads, n_waypoints=policy_waypoints)
    return {"take": take_id, "database": name, "episodes": aug["episodes"]}, q, ck
