"""The main job (`make evaluate`): default synthetic takes -> every flow -> reports/."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, get_run_logger

from demoforge.flows.augment import augment_take_flow
from demoforge.flows.closed_loop import data_scaling
from demoforge.flows.ingest import SIMULATED, ingest_side_by_side, ingest_take
from demoforge.flows.keypoint_eval import REAL_HANDS, evaluate_keypoints
from demoforge.flows.policy import evaluate_policy, train_policy
from demoforge.flows.screening import screen_task
from demoforge.flows.sim import check_stability, simulate_episodes
from demoforge.flows.synth import synthesize_takes
from demoforge.flows.table3 import table3
from demoforge.flows.variations import evaluate_variations
from demoforge.lib.errors import UnknownNameError
from demoforge.lib.evaluation.config import DETECTORS, ROBOTS, EvaluateConfig  # noqa: F401  (the CLI's choices)
from demoforge.lib.perception.detectors import DETECTORS as HAND_DETECTORS
from demoforge.lib.perception.detectors.mediapipe_backend import default_model_path
from demoforge.lib.settings import read_settings
from demoforge.lib.sim.variations import TABLE4_TASKS
from demoforge.lib.task_library import TASK_NAMES
from demoforge.lib.trajectories.augmentation.options import AugmentOptions
from demoforge.report.writer import write_report
from demoforge.runtime.artifacts import ProgressArtifact
from demoforge.runtime.runners import run_flow
from demoforge.tasks.policy import checkpoint_row
from demoforge.tasks.table3 import ALL_STRATEGIES, LLM_STRATEGIES, POLICY
from demoforge.tasks.variations import VARIATION_STRATEGIES


def detector_problem(name: str) -> str | None:
    """Why a detector cannot run here (its package or model file is missing), or None."""
    import importlib.util

    try:
        HAND_DETECTORS.check(name)
    except UnknownNameError as e:
        return str(e)
    if name == "mediapipe":  # checked without loading it: a run served from the cache never does
        if importlib.util.find_spec("mediapipe") is None:
            return "the mediapipe package is not installed: pip install --no-deps -r requirements/mediapipe.txt"
        if not default_model_path().is_file():
            return (f"the MediaPipe hand model {default_model_path()} is missing: "
                    "python scripts/fetch_mediapipe_model.py (make setup does)")
    return None


def _small_data_scaling(warehouse: str, c: EvaluateConfig, tasks: list[str]) -> None:
    """The small data-scaling table of the policy tasks with the first grid robot (flows/closed_loop.py)."""
    scaling_tasks = [t for t in c.policy_tasks if t in tasks]
    if c.scaling_scenes > 0 and scaling_tasks and c.grid_robots:
        run_flow(data_scaling, warehouse, tasks=scaling_tasks, sizes=c.scaling_sizes, scenes=c.scaling_scenes,
                 seed=c.seed, steps=c.scaling_steps, robot=c.grid_robot_specs[0], gripper=None, threads=2,
                 open_loop=False)  # Table 3's `policy` column with the arms is the open-loop policy already


@flow(name="evaluate")
def evaluate(warehouse: str, reports_dir: str, config: EvaluateConfig | None = None) -> str:
    """Generate the default synthetic takes (all six tasks, original and mirrored), run every stage
    on them and write reports/REPORT.md. Everything already computed comes from the cache.
    `config` (demoforge.lib.evaluation.config.EvaluateConfig; default: its defaults) says what runs;
    the names below are its fields.

    Every take is ingested with the simulated detector (and measured against its ground truth), and
    with each other detector of `detectors` beside it (demoforge.flows.ingest.ingest_side_by_side: its ingest
    accuracy, keypoint metrics and the robot executing its ingested demonstration, each detector in its
    own rows; with `detectors=["simulated"]` none of this runs: the cost of the main job before it);
    the first plain take of each task becomes that task's database of `episodes` episodes, every one screened
    for the arms of `grid_robots` (flows/screening.py: kinematics, no physics), of which `sim_episodes` (the
    original demonstration and a seeded sample of those the first of `grid_robots` can execute) are executed
    in MuJoCo by each of `robots` (the same sample, side by side: the floating grippers and the ALOHA arms
    with each hand), the LLM-free and policy columns of Table 3 also with `grid_robots`,
    and `stability_episodes` of them `stability_repeats` times by the first robot with the scene shifted
    by about 0.1 mm (how far a single verdict can be trusted).
    Table 3 (flows/table3.py, protocol `thesis`, the first take of each of `llm_tasks`): the LLM-free
    baselines and the learned policy on `grid_scenes` query scenes, the three prompts on the first
    `trials` of them with `llm_backend` (the embedded Gemma 3 270M by default: about 50 s per trial on 2
    cores with the thesis's numbers, 35 s with compact ones, so 1 by default; answers are cached). `make table3` runs the full grid.
    Keypoint accuracy (thesis Tables 1, 2, Appendix B) is measured on the synthetic takes, on the
    labelled real photos, and on ARCTIC when `arctic_root` (or $DEMOFORGE_ARCTIC_ROOT) is given."""
    c = config or EvaluateConfig()
    arctic_root = c.arctic_root or read_settings().arctic_root or None

    logger = get_run_logger()
    tasks = list(c.tasks) if c.tasks else list(TASK_NAMES)
    detectors = list(dict.fromkeys([SIMULATED, *c.detectors]))  # the simulated detector's ingest: always, first
    for name in detectors[1:]:
        problem = detector_problem(name)
        if problem:
            logger.warning("detector %s left out of the side-by-side ingest: %s", name, problem)
            detectors.remove(name)
    manifests = run_flow(synthesize_takes, warehouse, tasks=tasks, takes=c.takes, seed=c.seed, mirror=c.mirror)
    first_take: dict[str, str] = {}  # task -> path of its first plain take (the task database)
    progress = ProgressArtifact("evaluate-progress", len(manifests) + 2,
                                "The main job: takes processed, then the evaluations and the report.")
    for m in manifests:
        name = Path(m.path).name
        if name.endswith(f"_s{c.seed:04d}"):  # the first plain take of its task: the task database
            run_flow(augment_take_flow, m.path, warehouse, augment=AugmentOptions.half_mirrored(c.episodes, c.seed))
            task = name.split("_s")[0].removeprefix("synth_")
            first_take[task] = m.path
            for spec in c.grid_robot_specs:  # every episode checked for the arms, without physics
                run_flow(screen_task, warehouse, task=task, take=name, robot=spec.robot, gripper=spec.gripper)
            # the sample every robot executes: drawn from the episodes the (first) arms' screening lets through
            screened_for = c.grid_robots[0] if c.grid_robots else None
            for spec in c.robot_specs if c.sim_episodes else ():
                run_flow(simulate_episodes, warehouse, task=task, episodes=c.sim_episodes, take=name, seed=c.seed,
                         robot=spec, screened_for=screened_for)
            if c.stability_episodes and c.stability_repeats >= 2:
                run_flow(check_stability, warehouse, task=task, episodes=c.stability_episodes,
                         repeats=c.stability_repeats, take=name, seed=c.seed, robot=c.robot_specs[0])
        else:
            run_flow(ingest_take, m.path, warehouse)
        if len(detectors) > 1:
            run_flow(ingest_side_by_side, m.path, warehouse, detectors=detectors)
        progress.step()

    for llm_task in c.llm_tasks:
        if llm_task in first_take and c.grid_scenes > 0:
            with_policy = llm_task in c.policy_tasks and c.policy_trials > 0
            run_flow(table3, warehouse, task=llm_task, protocols=["thesis"], takes=1, scenes=c.grid_scenes,
                     llm_scenes=min(c.trials, c.grid_scenes), backend=c.llm_backend, backend_options=dict(c.llm_options),
                     strategies=[s for s in ALL_STRATEGIES if s != POLICY or with_policy], seed=c.seed,
                     episodes=c.episodes, policy_epochs=c.policy_epochs, policy_waypoints=c.policy_waypoints,
                     take_dirs=[first_take[llm_task]], structured=c.llm_structured, number_format=c.llm_number_format)
            for spec in c.grid_robot_specs:  # the arms beside it: the columns without an LLM
                run_flow(table3, warehouse, task=llm_task, protocols=["thesis"], takes=1, scenes=c.grid_scenes,
                         llm_scenes=0, strategies=[s for s in ALL_STRATEGIES if s not in LLM_STRATEGIES
                                                   and (s != POLICY or with_policy)],
                         seed=c.seed, episodes=c.episodes, policy_epochs=c.policy_epochs,
                         policy_waypoints=c.policy_waypoints, take_dirs=[first_take[llm_task]], robot=spec)

    for policy_task in c.policy_tasks:
        if policy_task in tasks and c.policy_trials > 0:
            # no time cap: a run that stops on a budget is not reproducible from its seed
            take = Path(first_take[policy_task]).name if policy_task in first_take else None
            ck = run_flow(train_policy, warehouse, task=policy_task, take=take, seed=c.seed, epochs=c.policy_epochs,
                          max_minutes=None, threads=2, n_waypoints=c.policy_waypoints)
            run_flow(evaluate_policy, warehouse, task=policy_task, take=take, trials=c.policy_trials, seed=c.seed,
                     checkpoint_id=checkpoint_row(ck)["checkpoint_id"])
    _small_data_scaling(warehouse, c, tasks)

    variation_tasks = [t for t in TABLE4_TASKS if t in tasks]
    if c.variation_trials > 0 and variation_tasks:
        run_flow(evaluate_variations, warehouse, tasks=variation_tasks, trials=c.variation_trials,
                 strategies=VARIATION_STRATEGIES, seed=c.seed)
    run_flow(evaluate_keypoints, warehouse, dataset="synthetic", takes=[Path(m.path).name for m in manifests])

    if REAL_HANDS.is_dir():
        run_flow(evaluate_keypoints, warehouse, dataset="real_photos")
    else:
        logger.warning("%s not found: the real-photo keypoint table is skipped", REAL_HANDS)
    if arctic_root:
        run_flow(evaluate_keypoints, warehouse, dataset="arctic", arctic_root=arctic_root)
    progress.step()
    shown = {**c.as_dict(), "tasks": tasks, "arctic_root": arctic_root, "detectors": detectors,
             "llm_number_format": c.llm_number_format or "thesis"}
    report = write_report(warehouse, reports_dir, shown)
    progress.step()
    logger.info("report written: %s", report)
    return str(report)
