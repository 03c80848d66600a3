"""`demoforge evaluate` (the main job), `augment`, `retrieve`, `simulate`, `stability`,
`render-episode`, `serve`."""

from __future__ import annotations

import os
from pathlib import Path
from typing import List, Optional
import typer

import demoforge.lib  # SHARED_DATA
from demoforge.cli.root import (TASK_HELP, current_warehouse, detector_option, fail, gripper_option,
                                llm_backend_option, number_format_option, robot_choice, robot_option, robot_spec,
                                structured_option, warn)
from demoforge.cli.screening import say_screening
from demoforge.cli.takes import _open_take_or_fail
from demoforge.cli.warehouse import OutputFormat, _emit
from demoforge.lib.settings import read_settings
from demoforge.runtime.runners import run_flow

app = typer.Typer()


@app.command()
def evaluate(
    reports: Path = typer.Option(Path("reports"), "--reports", help="Folder for REPORT.md, CSVs and figures."),
    task: Optional[List[str]] = typer.Option(None, "--task", "-t", help="Only these tasks (default: all six). " + TASK_HELP),
    takes: int = typer.Option(1, "--takes", min=1, envvar="DEMOFORGE_TAKES", help="Synthetic takes per task and mirror flag."),
    seed: int = typer.Option(0, envvar="DEMOFORGE_SEED", help="First seed of the synthetic takes."),
    mirror: str = typer.Option("both", envvar="DEMOFORGE_MIRROR", help="Synthetic takes: both (plain and mirrored), no (plain only) or yes (mirrored only)."),
    episodes: int = typer.Option(10_000, envvar="DEMOFORGE_EPISODES", min=1, help="Episodes per task database."),
    sim_episodes: int = typer.Option(20, envvar="DEMOFORGE_SIM_EPISODES", min=0, help="Episodes per task executed in MuJoCo (the original first)."),
    stability_episodes: int = typer.Option(10, envvar="DEMOFORGE_STABILITY_EPISODES", min=0, help="Of those, how many are executed again on copies of the scene shifted by about 0.1 mm (0 skips it)."),
    stability_repeats: int = typer.Option(3, envvar="DEMOFORGE_STABILITY_REPEATS", min=2, help="Executions per episode of the stability check (the first unshifted)."),
    trials: int = typer.Option(1, envvar="DEMOFORGE_TRIALS", min=0, help="Table 3 query scenes of the three LLM strategies on --llm-task (the first of --grid-scenes; thesis: 10; on 2 cores the local model takes about 50 s per trial with thesis numbers, 30-38 s with --number-format compact; 0 skips them). `make table3` runs the full grid."),
    grid_scenes: int = typer.Option(5, envvar="DEMOFORGE_GRID_SCENES", min=0, help="Table 3 query scenes (protocol thesis, first take) of the LLM-free baselines and the learned policy (0 skips Table 3)."),
    llm_task: Optional[List[str]] = typer.Option(None, "--llm-task", envvar="DEMOFORGE_LLM_TASKS", help="Tasks of the prompting evaluation (default: pouring)."),
    llm_backend: str = llm_backend_option("--llm-backend", help="local: offline Gemma 3 270M; openai: OPENAI_BASE_URL, OPENAI_API_KEY."),
    llm_model: Optional[str] = typer.Option(None, envvar="DEMOFORGE_LLM_MODEL", help="Model of the openai backend."),
    structured: Optional[bool] = structured_option(),
    number_format: Optional[str] = number_format_option(),
    variation_trials: int = typer.Option(2, "--variation-trials", envvar="DEMOFORGE_VARIATION_TRIALS", min=0, help="Scenes per task and variation kind of the Table 4 analogue (0 skips it)."),
    policy_epochs: int = typer.Option(6, envvar="DEMOFORGE_POLICY_EPOCHS", min=1, help="Training epochs of the learned policy (pouring)."),
    policy_trials: int = typer.Option(5, envvar="DEMOFORGE_POLICY_TRIALS", min=0, help="Scenes per kind the learned policy is judged on (0 skips training it)."),
    scaling_scenes: int = typer.Option(6, envvar="DEMOFORGE_SCALING_SCENES", min=0, help="Held-out scenes of the small data-scaling table (closed-loop policies of the policy tasks trained on 1 and 50 episodes, with the first --grid-robot; 0 skips it; `demoforge data-scaling` runs the full one)."),
    fresh: bool = typer.Option(False, "--fresh", help="Skip the whole-run check and let every stage confirm its own cache entry."),
    robot: Optional[List[str]] = typer.Option(None, "--robot", envvar="DEMOFORGE_ROBOTS", help="Robots every task's sample is executed with, side by side (repeatable; `name` or `name+hand`, one of: {robot_labels}; default: grippers, aloha and aloha+2f140: the floating grippers and the ViperX arms with ALOHA's fingers and with the 2F-140). The stability check and the Table 3 / Table 4 / policy evaluations use the first."),
    detector: Optional[List[str]] = typer.Option(None, "--detector", "-d", envvar="DEMOFORGE_DETECTORS", help="Hand detectors every take is ingested with, side by side (repeatable; those the main job runs: simulated and mediapipe, the default; registered: {detectors}). The simulated detector's ingest is always made (the later stages build on it); `--detector simulated` alone skips MediaPipe and the ingested-demonstration checks (about 15 s per take)."),
) -> None:
    """The main job: generate the default synthetic takes, run every stage, write reports/REPORT.md.

    A second run with nothing changed (parameters, code, warehouse files) returns at once; after a
    change, each stage is served from the cache unless its inputs changed.
    """
    # lazy (CLI start-up): numpy, pyarrow, scipy
    from demoforge.runtime import run_cache
    from demoforge.lib.task_library import TASK_NAMES

    unknown = [t for t in (task or []) if t not in TASK_NAMES]
    if unknown:
        raise fail(f"unknown task(s) {unknown}; choose from {', '.join(TASK_NAMES)}")
    from demoforge.lib.synth import MIRROR_CHOICES  # lazy (CLI start-up)

    if mirror not in MIRROR_CHOICES:
        raise fail(f"--mirror must be {', '.join(MIRROR_CHOICES[:-1])} or {MIRROR_CHOICES[-1]}, got {mirror!r}")
    from demoforge.flows.evaluate import detector_problem  # lazy: mujoco, prefect
    # lazy (CLI start-up)
    from demoforge.lib.evaluation.config import DETECTORS, ROBOTS, EvaluateConfig
    from demoforge.lib.robot_spec import RobotError

    robots = [r for part in (robot or ROBOTS) for r in str(part).replace(",", " ").split()]

    detectors = [d for part in (detector or DETECTORS) for d in str(part).replace(",", " ").split()]
    bad = [d for d in detectors if d not in DETECTORS]
    if bad:
        raise fail(f"--detector {bad[0]!r} is not one the main job runs; choose from {', '.join(DETECTORS)}")
    for d in detectors if detector else ():  # asked for by name: it must run (the default only warns)
        if detector_problem(d):
            raise fail(f"--detector {d}: {detector_problem(d)}")
    try:
        config = EvaluateConfig(
            tasks=task or None, takes=takes, seed=seed, mirror=mirror, episodes=episodes, sim_episodes=sim_episodes,
            stability_episodes=stability_episodes, stability_repeats=stability_repeats,
            llm_tasks=llm_task or ("pouring",), trials=trials, grid_scenes=grid_scenes, llm_backend=llm_backend,
            llm_options={"model": llm_model} if llm_model else {}, llm_structured=structured,
            llm_number_format=number_format, variation_trials=variation_trials, policy_epochs=policy_epochs,
            policy_trials=policy_trials, scaling_scenes=scaling_scenes, detectors=tuple(dict.fromkeys(detectors)),
            robots=tuple(dict.fromkeys(robots)))
    except RobotError as e:  # EvaluateConfig parses the labels (RobotSpec.parse), once
        raise fail(f"--robot: {e}")
    except ValueError as e:
        raise fail(str(e))
    warehouse, reports_dir = current_warehouse(), reports.resolve()
    key = run_cache.run_key({**config.as_dict(), "reports": str(reports_dir), "warehouse": str(warehouse)},
                            {"real_hands": str(demoforge.lib.SHARED_DATA / "real_hands"),
                             "arctic": str(read_settings().arctic_root or "") or None})
    if not fresh:
        cached = run_cache.lookup(warehouse, key)
        if cached is not None:
            typer.echo(f"nothing changed since the last complete run (same parameters, code and warehouse): {cached}")
            typer.echo("report: " + str(cached))
            return
    from demoforge.flows.evaluate import evaluate as evaluate_flow  # lazy: mujoco, prefect

    report = run_flow(evaluate_flow, str(warehouse), str(reports_dir), config)
    run_cache.remember(warehouse, key, report)
    typer.echo(f"report: {report}")


@app.command()
def augment(
    path: Path = typer.Argument(..., help="The demonstration's take folder or recording."),
    task: Optional[str] = typer.Option(None, help="Task of the take (synthetic takes know theirs)."),
    detector: str = detector_option(help="Detector used to ingest it."),
    episodes: int = typer.Option(10_000, "--episodes", "-n", min=1, help="Episodes to generate."),
    mirrored: int = typer.Option(5_000, help="How many of them are mirrored (arms' roles swapped)."),
    seed: int = typer.Option(0, help="Sampling seed."),
    mode: str = typer.Option("object", help="object (timing kept, segments follow their objects) or thesis (the thesis's 3.2 schedule)."),
    independent: bool = typer.Option(False, help="Place the two objects independently (each arm follows its own)."),
    yaw: float = typer.Option(0.0, help="Max rotation about the vertical, rad (the thesis translates only: 0)."),
    state_method: str = typer.Option("auto", help="As for `demoforge ingest`: the episodes come from the take's ingest with these mapping options."),
    smoothing: int = typer.Option(0, help="As for `demoforge ingest` (pose smoothing window, 0 = off)."),
    grasp_prior: str = typer.Option("pose", "--grasp-prior", help="As for `demoforge ingest`: pose, twist or off."),
    table_clearance: float = typer.Option(0.010, "--table-clearance", help="As for `demoforge ingest`, m; negative = off."),
    allow_untrusted_hands: bool = typer.Option(False, "--allow-untrusted-hands", help="Build the database even from a hand tracked in too few frames (see the hand_presence table)."),
    accept_bad_depth: bool = typer.Option(False, "--accept-bad-depth", help="As for `demoforge ingest`."),
    robot: Optional[str] = typer.Option(None, "--robot", help="Draw the placements for this robot's arms (aloha): those its screening rejects are drawn again (--redraw-rounds), then every episode is screened (as `demoforge screen`: the `episode_screening` table)."),
    gripper: Optional[str] = gripper_option(),
    redraw_rounds: int = typer.Option(8, "--redraw-rounds", min=0, help="With --robot: rounds of drawing again the placements the arms cannot serve (0: draw as without --robot, only screen)."),
) -> None:
    """Segment an ingested demonstration and generate the task's episode database (thesis 3.2-3.3).

    The episodes come from the take's ingest with the mapping options given here (the same defaults as
    `demoforge ingest`): give the values you ingested with, or the ingest is redone with these. With
    --robot aloha, the placements the arms cannot serve are drawn again (the same distribution, restricted to
    what the arms' screening passes) and each episode is then screened for the arms (`demoforge screen`)."""
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.annotate import annotation_status, not_annotated_message
    from demoforge.lib.takes import TakeError

    if robot is not None:
        from demoforge.flows.screening import check_robot  # lazy: prefect
        from demoforge.lib.sim.robots import RobotError  # lazy (CLI start-up): numpy, scipy

        robot, gripper = robot_choice(robot, gripper)
        try:
            check_robot(robot, gripper)
        except (RobotError, ValueError) as e:
            raise fail(str(e))

    status = annotation_status(_open_take_or_fail(path))
    if not status.annotated:  # episodes are placed by the object keypoints: stop before any flow runs
        raise fail(not_annotated_message(path, status.detail))
    from demoforge.flows.augment import augment_take_flow  # (Prefect and the flow's modules: once needed)
    # lazy (CLI start-up): numpy, scipy
    from demoforge.lib.ingest.options import IngestOptions
    from demoforge.lib.trajectories.augmentation.options import AugmentOptions

    try:
        augment_options = AugmentOptions(n=episodes, n_mirrored=mirrored, seed=seed, generation={
            "mode": mode, "independent": independent, "yaw_range": [-yaw, yaw]})
        ingest_options = IngestOptions(detector=detector, state_method=state_method, smoothing=smoothing,
                                       grasp_prior=grasp_prior,
                                       table_clearance=None if table_clearance < 0 else table_clearance,
                                       accept_bad_depth=accept_bad_depth)
        result = run_flow(augment_take_flow, str(path), str(current_warehouse()), task=task, augment=augment_options,
                          ingest=ingest_options, allow_untrusted_hands=allow_untrusted_hands,
                          robot=robot, gripper=gripper, redraw_rounds=redraw_rounds)
    except (TakeError, ValueError) as e:
        raise fail(str(e))
    typer.echo(f"episodes: {result['episodes'].path}")
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    t = query("SELECT kind, count(*) AS episodes, count(*) FILTER (WHERE valid) AS valid FROM episodes "
              "WHERE take = ? GROUP BY kind ORDER BY kind", current_warehouse(), [Path(path).resolve().name])
    _emit(t, OutputFormat.table, None, 10)
    _say_demo_check(result.get("demo_check"), path)
    if robot is not None:
        from demoforge.flows.screening import screen_task  # lazy: prefect

        take_id = Path(path).resolve().name
        for name in query("SELECT DISTINCT task FROM episodes WHERE take = ?", current_warehouse(), [take_id]).column(0).to_pylist():
            run_flow(screen_task, str(current_warehouse()), task=name, take=take_id, robot=robot, gripper=gripper)
            say_screening(name, robot, gripper)


def _say_demo_check(check, path: Path) -> None:
    """One line on the robot executing the ingested demonstration; a failure is a warning on stderr:
    every episode of the database is built from that trajectory."""
    from demoforge.schemas.core import read_table_file  # lazy (CLI start-up): pyarrow

    files = check.files if check is not None else []
    rows = [r for f in files for r in read_table_file("ingested_demo_checks", f).to_pylist()]
    if not rows:
        return
    r = rows[0]
    if r["success"]:
        typer.echo(f"robot check of the ingested demonstration: {r['detail']}")  # "success: ..."
    else:
        warn(f"the robot fails the ingested demonstration itself: {r['failure']} ({r['detail']}); "
             f"every episode of this database is built from it. Check the hand detections "
             f"(demoforge view {path} --rrd take.rrd) or ingest with another detector")


@app.command()
def retrieve(
    task: str = typer.Option(..., "--task", "-t", help="Task whose episodes to search. " + TASK_HELP),
    scene: Path = typer.Option(..., "--scene", exists=True, dir_okay=False, help='JSON {"object_keypoints": 11 x 3 world m}.'),
    k: int = typer.Option(3, "-k", min=1, help="How many episodes."),
    strategy: str = typer.Option("retrieval", help="retrieval (top-k keypoint MSE), random, or single (the original demo)."),
    metric: str = typer.Option("mse", help="mse, mse_mirrored (against the mirror image) or min (of both)."),
    take: Optional[str] = typer.Option(None, help="Only episodes generated from this take."),
    seed: int = typer.Option(0, help="Seed of the random strategy."),
    format: OutputFormat = typer.Option(OutputFormat.table, "--format", "-f"),
) -> None:
    """Pick episodes for a new scene: the thesis's top-k by object-keypoint MSE, or a baseline."""
    import pyarrow as pa

    from demoforge.flows.augment import read_scene, retrieve as run_retrieve  # lazy: prefect

    try:
        sc = read_scene(scene)
        rows = run_retrieve(str(current_warehouse()), task, sc["object_keypoints"], k=k, strategy=strategy,
                            metric=metric, take=take, seed=seed)
    except ValueError as e:
        raise fail(str(e))
    _emit(pa.Table.from_pylist(rows), format, None, k)


def _episodes_option(episodes: str) -> int | str:
    """--episodes of simulate / stability: a count or `all`."""
    if episodes == "all":
        return episodes
    if not episodes.isdigit():
        raise fail(f"--episodes must be a number or 'all', got {episodes!r}")
    return int(episodes)


@app.command()
def simulate(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episodes to check. " + TASK_HELP),
    episodes: str = typer.Option("100", "--episodes", "-n", help="How many (the original first, then a seeded sample of valid ones), or `all`."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); default: the task's first."),
    workers: int = typer.Option(2, min=1, help="Worker processes."),
    chunk_size: int = typer.Option(100, min=1, help="Episodes per cached chunk (a crash loses at most one chunk)."),
    seed: int = typer.Option(0, help="Seed of the episode sample."),
    robot: str = robot_option(),
    gripper: Optional[str] = gripper_option(),
    screened_for: Optional[str] = typer.Option(None, "--screened-for", help="Draw the episodes from those an arm robot's screening lets through (e.g. aloha+2f140; `demoforge screen` first): run every robot with the same --seed and this option to compare them on the same episodes."),
) -> None:
    """Execute episodes with a robot in MuJoCo physics and record success and failure reasons.

    --robot grippers (the default): two free-floating parallel-jaw grippers; --robot aloha: two ViperX
    300 arms through inverse kinematics, which also fail episodes they cannot reach (`unreachable`,
    `joint_limit`) or whose arm links hit the table, an object or the other arm (`link_collision`)."""
    from demoforge.flows.sim import simulate_episodes  # lazy: prefect

    spec = robot_spec(robot, gripper)  # checked once, here; the flow and its stages take it as it is
    robot, gripper = spec.robot, spec.gripper
    n = _episodes_option(episodes)
    try:
        run_flow(simulate_episodes, str(current_warehouse()), task=task, episodes=n, take=take, chunk_size=chunk_size,
                 workers=workers, seed=seed, robot=spec, screened_for=screened_for)
    except ValueError as e:
        raise fail(str(e))
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    wh = current_warehouse()
    result = query("SELECT * EXCLUDE (robot, gripper) FROM report_sim WHERE task = ? AND robot = ? AND gripper = ?",
                   wh, [task, robot, gripper])
    _emit(result, OutputFormat.table, None, 40)
    if sum(result.column("successes").to_pylist()) < sum(result.column("episodes").to_pylist()):
        typer.echo(f"Why: demoforge sql \"SELECT * FROM report_sim_failures WHERE task = '{task}' AND robot = '{robot}'\"."
                   f" Whether a failure is the trajectory's or chance: demoforge stability --task {task}"
                   + (f" --robot {robot} --gripper {gripper}" if robot != "grippers" else ""))


@app.command()
def stability(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episodes to check. " + TASK_HELP),
    episodes: str = typer.Option("40", "--episodes", "-n", help="How many (the original first, then a seeded sample of valid ones), or `all`."),
    repeats: int = typer.Option(5, min=2, help="Executions per episode: the scene as it is, then repeats - 1 shifted copies."),
    jitter: float = typer.Option(1e-4, help="Standard deviation of the rigid shift of the whole scene along the table, in metres "
                                 "(default 0.1 mm: physically nothing; only the simulation's rounding changes)."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); default: the task's first."),
    workers: int = typer.Option(2, min=1, help="Worker processes."),
    chunk_size: int = typer.Option(20, min=1, help="Episodes per cached chunk (each executed `repeats` times)."),
    seed: int = typer.Option(0, help="Seed of the episode sample and of the shifts."),
    robot: str = robot_option(),
    gripper: Optional[str] = gripper_option(),
) -> None:
    """Check how stable the robot check's verdicts are: execute each episode several times with the whole
    scene shifted by a fraction of a millimetre. An episode whose outcome flips is decided by numerical chaos, not by its
    trajectory; its success is a probability. Rows: `sim_stability`; summary: `report_sim_stability`."""
    from demoforge.flows.sim import check_stability  # lazy: prefect

    spec = robot_spec(robot, gripper)
    robot, gripper = spec.robot, spec.gripper
    n = _episodes_option(episodes)
    try:
        run_flow(check_stability, str(current_warehouse()), task=task, episodes=n, repeats=repeats, jitter_m=jitter,
                 take=take, chunk_size=chunk_size, workers=workers, seed=seed, robot=spec)
    except ValueError as e:
        raise fail(str(e))
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    _emit(query("SELECT * FROM report_sim_stability WHERE task = ? AND robot = ? AND gripper = ?", current_warehouse(),
                [task, robot, gripper]), OutputFormat.table, None, 40)


@app.command("render-episode")
def render_episode_cmd(
    task: str = typer.Option(..., "--task", "-t", help=TASK_HELP),
    episode: int = typer.Option(..., "--episode", "-e", help="Episode id (see the `episodes` table)."),
    out: Path = typer.Option(Path("episode.mp4"), "--out", "-o", help="Output MP4."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take)."),
    robot: str = robot_option(),
    gripper: Optional[str] = gripper_option(),
) -> None:
    """Render an offscreen video of the robot executing one episode."""
    from demoforge.flows.sim import render_episode_video  # lazy: prefect

    try:
        row = render_episode_video(str(current_warehouse()), task, episode, out, take=take,
                                   robot=robot_spec(robot, gripper))
    except ValueError as e:
        raise fail(str(e))
    typer.echo(f"{out}: {'success' if row['success'] else 'failed: ' + str(row['failure'])} ({row['detail']})")


@app.command()
def serve(
    inbox: Path = typer.Option(Path("takes/inbox"), help="Folder the scheduled deployment ingests takes from (created if missing)."),
    every: float = typer.Option(10.0, "--every", help="Minutes between scheduled ingests of the inbox."),
    reports: Path = typer.Option(Path("reports"), "--reports", help="Report folder of the evaluate deployment."),
    detector: str = detector_option(help="Detector of the scheduled ingest."),
    augment: bool = typer.Option(False, "--augment", help="Scheduled ingest also generates episode databases."),
    limit: int = typer.Option(1, min=1, help="Flow runs executed at the same time."),
) -> None:
    """Serve the Prefect deployments `ingest-folder/scheduled` and `evaluate/default` until Ctrl-C.

    Needs a Prefect server: `prefect server start` in another shell and PREFECT_API_URL pointing at it.
    Then trigger runs with `prefect deployment run 'evaluate/default' --watch`."""
    from demoforge.flows.deployments import serve_deployments  # lazy (CLI start-up): demoforge.flows

    if not os.environ.get("PREFECT_API_URL"):
        raise fail("PREFECT_API_URL is not set: start a server (`prefect server start --host 127.0.0.1 --port 4200 --analytics-off`) "
                   "and export PREFECT_API_URL=http://127.0.0.1:4200/api, so the deployments outlive this process")
    try:
        serve_deployments(str(current_warehouse()), str(inbox), str(reports), interval_minutes=every,
                          detector=detector, augment=augment, limit=limit)
    except ValueError as e:
        raise fail(str(e))
