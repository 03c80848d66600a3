"""The main job (`make evaluate`): default synthetic takes -> every flow -> reports/."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.runtime.artifacts import ProgressArtifact
from demoforge.flows.augment import augment_take_flow
from demoforge.flows.ingest import SIMULATED, ingest_side_by_side, ingest_take
from demoforge.flows.keypoint_eval import evaluate_keypoints
from demoforge.flows.report import write_report
from demoforge.runtime.runners import run_flow
from demoforge.flows.sim import check_stability, simulate_episodes
from demoforge.flows.synth import synthesize_takes
from demoforge.flows.table3 import table3

# The hand detectors `make evaluate` ingests every take with, side by side: the simulated one (the ground
# truth through an error model; every later stage builds on its ingest) and MediaPipe, a real detector.
DETECTORS = (SIMULATED, "mediapipe")


def detector_problem(name: str) -> str | None:
    """Why a detector cannot run here (its package or model file is missing), or None."""
    import importlib.util

    from demoforge.lib.perception.detectors import available_detectors

    if name not in available_detectors():
        return f"unknown detector {name!r}; choose from {', '.join(available_detectors())}"
    if name == "mediapipe":  # checked without loading it: a run served from the cache never does
        from demoforge.lib.perception.detectors.mediapipe_backend import default_model_path

        if importlib.util.find_spec("mediapipe") is None:
            return "the mediapipe package is not installed: pip install --no-deps -r requirements/mediapipe.txt"
        if not default_model_path().is_file():
            return (f"the MediaPipe hand model {default_model_path()} is missing: "
                    "python scripts/fetch_mediapipe_model.py (make setup does)")
    return None


@flow(name="evaluate")
def evaluate(
    warehouse: str,
    reports_dir: str,
    tasks: Sequence[str] | None = None,
    takes: int = 1,
    seed: int = 0,
    mirror: str = "both",
    episodes: int = 10_000,
    arctic_root: str | None = None,
    sim_episodes: int = 20,
    stability_episodes: int = 10,
    stability_repeats: int = 3,
    llm_tasks: Sequence[str] = ("pouring",),
    trials: int = 1,
    grid_scenes: int = 5,
    llm_backend: str = "local",
    llm_options: dict | None = None,
    llm_structured: bool | None = None,
    llm_number_format: str | None = None,
    variation_trials: int = 2,
    policy_tasks: Sequence[str] = ("pouring",),
    policy_epochs: int = 6,
    policy_waypoints: int = 40,
    policy_trials: int = 5,
    detectors: Sequence[str] = DETECTORS,
) -> str:
    """Generate the default synthetic takes (all six tasks, original and mirrored), run every stage
    on them and write reports/REPORT.md. Everything already computed comes from the cache.

    Every take is ingested with the simulated detector (and measured against its ground truth), and
    with each other detector of `detectors` beside it (demoforge.flows.ingest.ingest_side_by_side: its ingest
    accuracy, keypoint metrics and the robot executing its ingested demonstration, each detector in its
    own rows; with `detectors=["simulated"]` none of this runs: the cost of the main job before it);
    the first plain take of each task becomes that task's database of `episodes` episodes, of which
    `sim_episodes` (the original demonstration and a seeded sample) are executed by the robot in MuJoCo,
    and `stability_episodes` of them `stability_repeats` times with the scene shifted by about 0.1 mm (how
    far a single verdict can be trusted).
    Table 3 (flows/table3.py, protocol `thesis`, the first take of each of `llm_tasks`): the LLM-free
    baselines and the learned policy on `grid_scenes` query scenes, the three prompts on the first
    `trials` of them with `llm_backend` (the embedded Gemma 3 270M by default: about a minute per trial on 2
    cores, so 1 by default; answers are cached). `make table3` runs the full grid.
    Keypoint accuracy (thesis Tables 1, 2, Appendix B) is measured on the synthetic takes, on the
    labelled real photos, and on ARCTIC when `arctic_root` (or $DEMOFORGE_ARCTIC_ROOT) is given."""
    from demoforge.lib.settings import read_settings

    arctic_root = arctic_root or read_settings().arctic_root or None
    from demoforge.lib.task_library import TASK_NAMES

    logger = get_run_logger()
    tasks = list(tasks) if tasks else list(TASK_NAMES)
    detectors = list(dict.fromkeys([SIMULATED, *detectors]))  # the simulated detector's ingest: always, first
    for name in detectors[1:]:
        problem = detector_problem(name)
        if problem:
            logger.warning("detector %s left out of the side-by-side ingest: %s", name, problem)
            detectors.remove(name)
    manifests = run_flow(synthesize_takes, warehouse, tasks=tasks, takes=takes, seed=seed, mirror=mirror)
    first_take: dict[str, str] = {}  # task -> path of its first plain take (the task database)
    progress = ProgressArtifact("evaluate-progress", len(manifests) + 2,
                                "The main job: takes processed, then the evaluations and the report.")
    for m in manifests:
        name = Path(m.path).name
        if name.endswith(f"_s{seed:04d}"):  # the first plain take of its task: the task database
            run_flow(augment_take_flow, m.path, warehouse, n=episodes, n_mirrored=episodes // 2, seed=seed)
            task = name.split("_s")[0].removeprefix("synth_")
            first_take[task] = m.path
            if sim_episodes:
                run_flow(simulate_episodes, warehouse, task=task, episodes=sim_episodes, take=name, seed=seed)
            if stability_episodes and stability_repeats >= 2:
                run_flow(check_stability, warehouse, task=task, episodes=stability_episodes,
                         repeats=stability_repeats, take=name, seed=seed)
        else:
            run_flow(ingest_take, m.path, warehouse)
        if len(detectors) > 1:
            run_flow(ingest_side_by_side, m.path, warehouse, detectors=detectors)
        progress.step()
    from demoforge.tasks.table3 import ALL_STRATEGIES, POLICY

    for llm_task in llm_tasks:
        if llm_task in first_take and grid_scenes > 0:
            with_policy = llm_task in policy_tasks and policy_trials > 0
            run_flow(table3, warehouse, task=llm_task, protocols=["thesis"], takes=1, scenes=grid_scenes,
                     llm_scenes=min(trials, grid_scenes), backend=llm_backend, backend_options=llm_options or {},
                     strategies=[s for s in ALL_STRATEGIES if s != POLICY or with_policy], seed=seed,
                     episodes=episodes, policy_epochs=policy_epochs, policy_waypoints=policy_waypoints,
                     take_dirs=[first_take[llm_task]], structured=llm_structured, number_format=llm_number_format)
    from demoforge.flows.policy import evaluate_policy, train_policy
    from demoforge.tasks.policy import checkpoint_row

    for policy_task in policy_tasks:
        if policy_task in tasks and policy_trials > 0:
            # no time cap: a run that stops on a budget is not reproducible from its seed
            take = Path(first_take[policy_task]).name if policy_task in first_take else None
            ck = run_flow(train_policy, warehouse, task=policy_task, take=take, seed=seed, epochs=policy_epochs,
                          max_minutes=None, threads=2, n_waypoints=policy_waypoints)
            run_flow(evaluate_policy, warehouse, task=policy_task, take=take, trials=policy_trials, seed=seed,
                     checkpoint_id=checkpoint_row(ck)["checkpoint_id"])
    from demoforge.flows.variations import evaluate_variations
    from demoforge.lib.sim.variations import TABLE4_TASKS
    from demoforge.tasks.variations import VARIATION_STRATEGIES

    variation_tasks = [t for t in TABLE4_TASKS if t in tasks]
    if variation_trials > 0 and variation_tasks:
        run_flow(evaluate_variations, warehouse, tasks=variation_tasks, trials=variation_trials,
                 strategies=VARIATION_STRATEGIES, seed=seed)
    run_flow(evaluate_keypoints, warehouse, dataset="synthetic", takes=[Path(m.path).name for m in manifests])
    from demoforge.flows.keypoint_eval import REAL_HANDS

    if REAL_HANDS.is_dir():
        run_flow(evaluate_keypoints, warehouse, dataset="real_photos")
    else:
        logger.warning("%s not found: the real-photo keypoint table is skipped", REAL_HANDS)
    if arctic_root:
        run_flow(evaluate_keypoints, warehouse, dataset="arctic", arctic_root=arctic_root)
    progress.step()
    report = write_report(warehouse, reports_dir, {"tasks": tasks, "takes": takes, "seed": seed,
                                                   "mirror": mirror, "episodes": episodes,
                                                   "arctic_root": arctic_root, "sim_episodes": sim_episodes,
                                                   "stability_episodes": stability_episodes,
                                                   "stability_repeats": stability_repeats,
                                                   "llm_tasks": list(llm_tasks), "trials": trials,
                                                   "grid_scenes": grid_scenes,
                                                   "llm_backend": llm_backend,
                                                   "llm_structured": llm_structured,
                                                   "llm_number_format": llm_number_format or "thesis",
                                                   "variation_trials": variation_trials,
                                                   "policy_epochs": policy_epochs, "policy_trials": policy_trials,
                                                   "policy_waypoints": policy_waypoints,
                                                   "detectors": detectors})
    progress.step()
    logger.info("report written: %s", report)
    return str(report)
