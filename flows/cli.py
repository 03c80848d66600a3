"""`demoforge`: the command line. Each command is a thin call into a flow or the catalog."""

from __future__ import annotations

import enum
import os
import sys
from pathlib import Path
from typing import List, Optional

import click
import typer
from typer.core import TyperGroup

import lib  # noqa: F401  (sets MUJOCO_GL before anything imports mujoco)
from flows.runners import run_flow


# Click's own exits and usage errors (typer vendors click: both its copy's classes and click's)
_tclick = getattr(typer.core, "_click", click)
_CLICK_OWN = (typer.Exit, typer.Abort, click.exceptions.Exit, click.exceptions.Abort, click.ClickException,
              _tclick.ClickException)


class _ErrorsAtTheBoundary(TyperGroup):
    """Every command's errors end here: a user error (lib.errors) is one line on stderr and exit code 2,
    whichever command or flow raised it; a crash is a short summary with the hint to rerun with
    --debug (exit code 1); with --debug both keep their full traceback."""

    def invoke(self, ctx: click.Context):
        from lib.errors import is_user_error, one_line

        try:
            return super().invoke(ctx)
        except _CLICK_OWN:
            raise
        except Exception as e:
            if State.debug:
                raise
            if is_user_error(e):
                raise fail(one_line(e))
            import traceback

            where = traceback.extract_tb(e.__traceback__)[-1]
            typer.echo(f"error: demoforge crashed: {type(e).__name__}: {one_line(e, 300)} "
                       f"(at {where.filename}:{where.lineno}); this is a bug, not your input: rerun with "
                       f"--debug (demoforge --debug COMMAND ...) for the full traceback and report it", err=True)
            raise typer.Exit(1)


app = typer.Typer(
    cls=_ErrorsAtTheBoundary,
    name="demoforge",
    help=(
        "Turn one RGB-D video of a two-handed human demonstration into thousands of dual-arm robot "
        "episodes, and measure how good they are. All results are Parquet tables in the warehouse "
        "(default ./warehouse, or $DEMOFORGE_WAREHOUSE, or --warehouse), queryable with `demoforge sql`."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

EXIT_USER_ERROR = 2


def fail(message: str) -> "typer.Exit":
    """Print a one-line error to stderr and return the exit to raise (code 2)."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(EXIT_USER_ERROR)


class State:
    warehouse: Optional[Path] = None
    debug: bool = False


def current_warehouse() -> Path:
    from schemas.catalog import warehouse_root

    return warehouse_root(State.warehouse)


@app.callback()
def _main(
    warehouse: Optional[Path] = typer.Option(
        None, "--warehouse", "-w", envvar="DEMOFORGE_WAREHOUSE",
        help="Warehouse folder (Parquet tables + catalog.duckdb). Default: ./warehouse of the project.",
    ),
    task_runner: Optional[str] = typer.Option(
        None, "--task-runner", envvar="DEMOFORGE_TASK_RUNNER",
        help="Where tasks run: threads (default, this process) or dask (a Dask cluster, see --dask-address).",
    ),
    dask_address: Optional[str] = typer.Option(
        None, "--dask-address", envvar="DEMOFORGE_DASK_ADDRESS",
        help="Scheduler of an existing Dask cluster (tcp://host:8786); without it, --task-runner dask starts "
             "a local cluster of $DEMOFORGE_DASK_WORKERS (default 2) worker processes.",
    ),
    debug: bool = typer.Option(
        False, "--debug", envvar="DEMOFORGE_DEBUG",
        help="Show full tracebacks: of crashes, and of user errors too (normally one line, exit code 2).",
    ),
) -> None:
    from flows import runners
    from lib.errors import Reporting

    State.warehouse = warehouse
    State.debug = debug
    Reporting.cli_reports, Reporting.show_tracebacks = True, debug
    if "tasks.common" in sys.modules:  # else its import installs the filters (Prefect only when needed)
        sys.modules["tasks.common"].quiet_user_errors()
    runners.install_interrupt_handler()
    if task_runner:
        os.environ[runners.ENV_RUNNER] = task_runner
    if dask_address:
        os.environ[runners.ENV_ADDRESS] = dask_address
    try:
        kind = runners.runner_kind()
        if kind == "dask" and not dask_address:
            runners.dask_workers()
    except ValueError as e:
        raise fail(str(e))


class OutputFormat(str, enum.Enum):
    table = "table"
    csv = "csv"
    json = "json"
    parquet = "parquet"


@app.command()
def sql(
    query: str = typer.Argument(..., help='One read-only statement, e.g. "SELECT * FROM benchmarks LIMIT 5".'),
    format: OutputFormat = typer.Option(OutputFormat.table, "--format", "-f", help="Output format."),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="Write to this file instead of stdout (required for parquet)."),
    max_rows: int = typer.Option(40, help="Rows shown in `table` format (the rest are elided)."),
) -> None:
    """Run a read-only SQL query over the warehouse (DuckDB) and print or save the result.

    Every table is a view in warehouse/catalog.duckdb; `demoforge tables` lists them with their
    columns. Statements that would write (INSERT, DROP, COPY, ...) are refused with exit code 2, and
    so are reads of anything but the warehouse's tables (read_text, read_csv, ATTACH, URLs, ...).
    """
    from schemas.catalog import QueryRefused, query as run_query

    try:
        result = run_query(query, current_warehouse())
    except QueryRefused as e:
        raise fail(str(e))
    _emit(result, format, output, max_rows)


def _emit(result, fmt: OutputFormat, output: Optional[Path], max_rows: int) -> None:
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    if fmt is OutputFormat.parquet:
        if output is None:
            raise fail("--format parquet needs --output FILE")
        pq.write_table(result, output)
        typer.echo(f"wrote {result.num_rows} rows to {output}", err=True)
        return
    if fmt is OutputFormat.csv:
        import io

        buf = io.BytesIO()
        pacsv.write_csv(_flatten_lists_for_csv(result), buf)
        text = buf.getvalue().decode()
    elif fmt is OutputFormat.json:
        import json

        text = "\n".join(json.dumps(r, default=str) for r in result.to_pylist()) + ("\n" if result.num_rows else "")
    else:
        text = _pretty(result, max_rows)
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text)
        typer.echo(f"wrote {result.num_rows} rows to {output}", err=True)


def _flatten_lists_for_csv(result):
    """CSV has no arrays: list columns are written as JSON text."""
    import json

    import pyarrow as pa

    cols = []
    for name in result.column_names:
        col = result.column(name)
        t = col.type
        if pa.types.is_list(t) or pa.types.is_fixed_size_list(t) or pa.types.is_large_list(t) or pa.types.is_struct(t):
            col = pa.array([json.dumps(v) for v in col.to_pylist()], pa.string())
        cols.append(col)
    return pa.table(cols, names=result.column_names)


def _pretty(result, max_rows: int) -> str:
    import duckdb

    con = duckdb.connect()
    try:
        rel = con.from_arrow(result)
        text = rel.limit(max_rows).__str__() if result.num_rows > max_rows else str(rel)
    finally:
        con.close()
    if result.num_rows > max_rows:
        text += f"({result.num_rows} rows, {max_rows} shown; use --max-rows or --format csv)\n"
    return text


@app.command()
def catalog() -> None:
    """Rebuild warehouse/catalog.duckdb: one DuckDB view per table, over its Parquet files."""
    from schemas.catalog import build_catalog

    path = build_catalog(current_warehouse())
    typer.echo(f"catalog rebuilt: {path}")


@app.command()
def tables(
    name: Optional[str] = typer.Argument(None, help="Describe this table column by column."),
) -> None:
    """List the warehouse tables with their row counts, or describe one table's columns."""
    from schemas import registry
    from schemas.core import ALL_VARIANTS, get_schema, table_files

    root = current_warehouse()
    if name:
        try:
            schema = get_schema(name)
        except KeyError as e:
            raise fail(str(e.args[0]))
        typer.echo(schema.describe())
        return
    import pyarrow.parquet as pq

    for tname, schema in sorted(registry().items()):
        files = table_files(tname, root, ALL_VARIANTS)  # a second detector's rows too (schemas.core.variant_parts)
        rows = sum(pq.ParquetFile(f).metadata.num_rows for f in files)
        typer.echo(f"{tname:<24} v{schema.version}  {rows:>10} rows  {len(files):>5} files  {schema.doc.splitlines()[0][:70]}")


@app.command()
def bench(
    stage: Optional[List[str]] = typer.Option(None, "--stage", "-s", help="Only these stages (repeatable)."),
    quick: bool = typer.Option(False, help="Smaller inputs, for a fast smoke run."),
) -> None:
    """Benchmark every stage against a straightforward baseline; rows go to the `benchmarks` table."""
    from flows.bench import run_benchmarks

    try:
        rows = run_benchmarks(str(current_warehouse()), stages=stage, quick=quick)
    except ValueError as e:
        raise fail(str(e))
    header = f"{'stage':<12} {'case':<44} {'size':>9} {'unit':<9} {'seconds':>9} {'baseline s':>10} {'ratio':>8}"
    typer.echo(header)
    typer.echo("-" * len(header))
    for r in rows:
        typer.echo(
            f"{r['stage']:<12} {r['case_name'][:44]:<44} {r['size']:>9} {r['unit']:<9} "
            f"{r['seconds']:>9.4f} {r['baseline_seconds']:>10.4f} {r['ratio']:>7.1f}x"
        )
    if rows:
        typer.echo(f"machine: {rows[0]['machine']}; commit {rows[0]['git_commit']}; run {rows[0]['run_id']}")


@app.command()
def synth(
    task: List[str] = typer.Option(["pouring"], "--task", "-t", help="Task(s) to generate (repeatable), or `all`."),
    takes: int = typer.Option(1, "--takes", "-n", min=1, help="Takes per task (seeds seed, seed+1, ...)."),
    seed: int = typer.Option(0, help="First seed; a take is fully determined by (task, seed, mirror)."),
    mirror: bool = typer.Option(False, "--mirror", help="Write the mirrored variant (hands' roles swapped)."),
    both: bool = typer.Option(False, "--both", help="Write the original and the mirrored variant."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Folder for the take folders. Default: <warehouse>/synthetic."),
    depth_noise: bool = typer.Option(True, help="Add realistic depth noise and holes (0 = invalid)."),
    video: bool = typer.Option(True, help="Also write rgb.mp4 per take."),
    max_frames: Optional[int] = typer.Option(None, help="Keep only the first N frames (previews)."),
    hand_style: str = typer.Option("capsule", "--hand-style", help="Look of the hands: capsule (default) or skin (palm, forearm, sleeve, nails: what a real detector finds far more often; the depth at the wrist and thumb base differs from what the ingest's alignment assumes, see README). The ground truth is the same."),
) -> None:
    """Generate synthetic RGB-D demonstrations with exact ground truth (MuJoCo renders).

    Each take folder has the layout of a real recording (rgb/, depth/, camera.json,
    annotations.json, rgb.mp4) plus ground_truth/ tables; takes are registered in the `takes`
    table and their ground truth in the gt_* tables of the warehouse.
    """
    from flows.synth import synthesize_takes
    from lib.task_library import TASK_NAMES

    tasks = list(TASK_NAMES) if "all" in task else task
    unknown = [t for t in tasks if t not in TASK_NAMES]
    if unknown:
        raise fail(f"unknown task(s) {unknown}; choose from: all, {', '.join(TASK_NAMES)}")
    if hand_style not in ("skin", "capsule"):
        raise fail(f"--hand-style must be skin or capsule, got {hand_style!r}")
    manifests = run_flow(
        synthesize_takes,
        str(current_warehouse()), tasks=tasks, takes=takes, seed=seed,
        mirror="both" if both else ("yes" if mirror else "no"),
        takes_dir=str(out) if out else None, depth_noise=depth_noise, video=video, max_frames=max_frames,
        hand_style=hand_style,
    )
    for m in manifests:
        typer.echo(m.path)


@app.command()
def evaluate(
    reports: Path = typer.Option(Path("reports"), "--reports", help="Folder for REPORT.md, CSVs and figures."),
    task: Optional[List[str]] = typer.Option(None, "--task", "-t", help="Only these tasks (default: all six)."),
    takes: int = typer.Option(1, "--takes", min=1, envvar="TAKES", help="Synthetic takes per task and mirror flag."),
    seed: int = typer.Option(0, envvar="SEED", help="First seed of the synthetic takes."),
    mirror: str = typer.Option("both", envvar="MIRROR", help="Synthetic takes: both (plain and mirrored), no (plain only) or yes (mirrored only)."),
    episodes: int = typer.Option(10_000, envvar="EPISODES", min=1, help="Episodes per task database."),
    sim_episodes: int = typer.Option(20, envvar="SIM_EPISODES", min=0, help="Episodes per task executed in MuJoCo (the original first)."),
    stability_episodes: int = typer.Option(10, envvar="STABILITY_EPISODES", min=0, help="Of those, how many are executed again on copies of the scene shifted by about 0.1 mm (0 skips it)."),
    stability_repeats: int = typer.Option(3, envvar="STABILITY_REPEATS", min=2, help="Executions per episode of the stability check (the first unshifted)."),
    trials: int = typer.Option(1, envvar="TRIALS", min=0, help="Table 3 query scenes of the three LLM strategies on --llm-task (the first of --grid-scenes; thesis: 10; on 2 cores the local model takes 1-2 min per trial and strategy; 0 skips them). `make table3` runs the full grid."),
    grid_scenes: int = typer.Option(5, envvar="GRID_SCENES", min=0, help="Table 3 query scenes (protocol thesis, first take) of the LLM-free baselines and the learned policy (0 skips Table 3)."),
    llm_task: Optional[List[str]] = typer.Option(None, "--llm-task", envvar="LLM_TASKS", help="Tasks of the prompting evaluation (default: pouring)."),
    llm_backend: str = typer.Option("local", envvar="LLM_BACKEND", help="local (offline Gemma 3 270M) or openai (OPENAI_BASE_URL, OPENAI_API_KEY)."),
    llm_model: Optional[str] = typer.Option(None, envvar="LLM_MODEL", help="Model of the openai backend."),
    variation_trials: int = typer.Option(2, "--variation-trials", envvar="VARIATION_TRIALS", min=0, help="Scenes per task and variation kind of the Table 4 analogue (0 skips it)."),
    policy_epochs: int = typer.Option(6, envvar="POLICY_EPOCHS", min=1, help="Training epochs of the learned policy (pouring)."),
    policy_trials: int = typer.Option(5, envvar="POLICY_TRIALS", min=0, help="Scenes per kind the learned policy is judged on (0 skips training it)."),
    fresh: bool = typer.Option(False, "--fresh", help="Skip the whole-run check and let every stage confirm its own cache entry."),
    detector: Optional[List[str]] = typer.Option(None, "--detector", "-d", envvar="DEMOFORGE_DETECTORS", help="Hand detectors every take is ingested with, side by side (repeatable; default: simulated and mediapipe). The simulated detector's ingest is always made (the later stages build on it); `--detector simulated` alone skips MediaPipe and the ingested-demonstration checks (about 15 s per take)."),
) -> None:
    """The main job: generate the default synthetic takes, run every stage, write reports/REPORT.md.

    A second run with nothing changed (parameters, code, warehouse files) returns at once; after a
    change, each stage is served from the cache unless its inputs changed.
    """
    from flows import run_cache
    from lib.task_library import TASK_NAMES

    unknown = [t for t in (task or []) if t not in TASK_NAMES]
    if unknown:
        raise fail(f"unknown task(s) {unknown}; choose from {', '.join(TASK_NAMES)}")
    if mirror not in ("both", "no", "yes"):
        raise fail(f"--mirror must be both, no or yes, got {mirror!r}")
    from flows.evaluate import DETECTORS, detector_problem

    detectors = [d for part in (detector or DETECTORS) for d in str(part).replace(",", " ").split()]
    bad = [d for d in detectors if d not in DETECTORS]
    if bad:
        raise fail(f"--detector {bad[0]!r} is not one the main job runs; choose from {', '.join(DETECTORS)}")
    for d in detectors if detector else ():  # asked for by name: it must run (the default only warns)
        if detector_problem(d):
            raise fail(f"--detector {d}: {detector_problem(d)}")
    params = dict(tasks=task or None, takes=takes, seed=seed, mirror=mirror, episodes=episodes,
                  sim_episodes=sim_episodes, stability_episodes=stability_episodes,
                  stability_repeats=stability_repeats, llm_tasks=llm_task or ["pouring"], trials=trials, grid_scenes=grid_scenes,
                  llm_backend=llm_backend, llm_options={"model": llm_model} if llm_model else {},
                  variation_trials=variation_trials, policy_epochs=policy_epochs, policy_trials=policy_trials,
                  detectors=list(dict.fromkeys(detectors)))
    warehouse, reports_dir = current_warehouse(), reports.resolve()
    key = run_cache.run_key({**params, "reports": str(reports_dir), "warehouse": str(warehouse)},
                            {"real_hands": str(lib.SHARED_DATA / "real_hands"),
                             "arctic": os.environ.get("ARCTIC_ROOT")})
    if not fresh:
        cached = run_cache.lookup(warehouse, key)
        if cached is not None:
            typer.echo(f"nothing changed since the last complete run (same parameters, code and warehouse): {cached}")
            typer.echo("report: " + str(cached))
            return
    from flows.evaluate import evaluate as evaluate_flow

    report = run_flow(evaluate_flow, str(warehouse), str(reports_dir), **params)
    run_cache.remember(warehouse, key, report)
    typer.echo(f"report: {report}")


def _open_take_or_fail(path: Path):
    """The opened take, or a one-line error (exit 2) before any flow starts: missing folder, missing or
    malformed camera.json / annotations.json."""
    from lib.ingest import TakeError, open_take

    if not path.is_dir():
        raise fail(f"{path}: no such take folder" if not path.exists() else f"{path}: is a file, not a take folder")
    try:
        return open_take(path)
    except (TakeError, FileNotFoundError) as e:
        raise fail(str(e))


@app.command()
def annotate(
    path: Path = typer.Argument(..., help="Take folder (rgb/ or .mp4, depth/, camera.json)."),
    task: Optional[str] = typer.Option(None, "--task", "-t", help="Task of the take (pouring, ...), or `custom` / "
                                       "`custom:NAME` (with --keypoints) for a task of your own. Default: what "
                                       "annotations.json says."),
    keypoints: Optional[str] = typer.Option(None, "--keypoints", help="For --task custom: 11 keypoint names, comma "
                                            "separated; `object:name` puts a keypoint on an object (at most two objects)."),
    task_file: Optional[Path] = typer.Option(None, "--task-file", help='A task of your own as JSON: {"name": ..., '
                                             '"objects": [{"name": ..., "arm": "left"|"right", "keypoints": [...]}]}.'),
    port: int = typer.Option(8765, "--port", "-p", min=0, max=65535, help="Port on 127.0.0.1 (0: any free port)."),
    open_browser: bool = typer.Option(False, "--open", help="Also open the page in the default browser."),
) -> None:
    """Annotate a take in the browser: click the object keypoints, mark gripper open/close ranges, save.

    Serves a page on 127.0.0.1 (printed) until Ctrl-C. It shows the frames (scrub with the slider or
    the arrow keys), asks for the task's keypoints one by one and shows each click's depth and world
    position, and plots the fingertip distance of an earlier `demoforge ingest` with the automatic
    method's closed ranges pre-filled. Save writes TAKE/annotations.json (an existing one is edited).
    """
    from flows.annotate import AnnotationSession, server_url, start_server
    from lib.ingest import TakeError

    _open_take_or_fail(path)
    try:
        session = AnnotationSession(path, current_warehouse(), task=task, keypoints=keypoints, task_file=task_file)
    except TakeError as e:
        raise fail(str(e))
    try:
        server = start_server(session, port=port)
    except OSError as e:
        raise fail(f"cannot listen on 127.0.0.1:{port} ({e.strerror or e}); choose another --port")
    url = server_url(server)
    typer.echo(f"annotating {session.take.path} (task {session.task.name}): open {url}  (Ctrl-C to stop)", err=True)
    typer.echo(url)
    if open_browser:
        import webbrowser

        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()


@app.command()
def ingest(
    path: Path = typer.Argument(..., help="Take folder (rgb/ or .mp4, depth/, camera.json)."),
    detector: str = typer.Option("simulated", "--detector", "-d", help="simulated (synthetic takes), mediapipe, precomputed, hamer (local checkpoint)."),
    predictions: Optional[Path] = typer.Option(None, help="For --detector precomputed: thesis-code keypoint JSON, or Parquet/NPZ predictions."),
    task: Optional[str] = typer.Option(None, help="Task of the take (needed later to augment a recorded take)."),
    state_method: str = typer.Option("auto", help="Open/close when the take has no labelled ranges: auto, otsu or threshold."),
    smoothing: int = typer.Option(0, help="Segment-wise pose smoothing window in frames (0 = off)."),
    video: bool = typer.Option(False, "--video", help="Also write an MP4 with the skeletons and gripper frames drawn on the frames."),
    hamer_checkpoint: Optional[Path] = typer.Option(None, "--hamer-checkpoint", help="For --detector hamer: local hamer.ckpt (licensed; never downloaded)."),
    mano_model: Optional[Path] = typer.Option(None, "--mano-model", help="For --detector hamer: local MANO_RIGHT.pkl (licensed; never downloaded)."),
    grasp_prior: str = typer.Option("pose", "--grasp-prior", help="While a hand is closed the grasp is rigid: 'pose' takes the pinch pose (position and rotation) from the whole hand's motion (default), 'twist' only the twist about the approach axis, 'off' keeps the thesis's mapping."),
    table_clearance: float = typer.Option(0.010, "--table-clearance", help="Lowest pinch height above the table top, m (fingertips cannot go below the table); negative = off."),
    box_source: str = typer.Option("previous", "--box-source", help="For --detector hamer: 'previous' (last frame's keypoints; MediaPipe finds untracked hands) or 'mediapipe' (every frame)."),
    accept_bad_depth: bool = typer.Option(False, "--accept-bad-depth", help="Go on when the take's depth fails a check (empty, wrong unit, misaligned): every row is flagged in `depth_problem` instead of stopping."),
    mediapipe_mode: str = typer.Option("auto", "--mediapipe-mode", help="For --detector mediapipe: auto (video mode: landmark tracking between palm detections; default) or image (every frame on its own)."),
) -> None:
    """Ingest one take: frames, hand keypoints, depth checks, hand tracking, depth alignment, gripper
    poses, object keypoints.

    Results go to the warehouse tables frames, hand_keypoints, aligned_keypoints, hand_presence,
    gripper_poses, object_keypoints (and ingest_metrics for synthetic takes, against their ground
    truth). Depth that cannot be trusted stops the take (exit 2) unless --accept-bad-depth; a hand
    tracked in too few frames is reported as not trusted (and `augment` refuses it).
    """
    from flows.ingest import ingest_take
    from lib.detectors import DetectorError
    from lib.ingest import TakeError

    options = {}
    if detector == "mediapipe" and mediapipe_mode != "auto":
        if mediapipe_mode not in ("image", "video"):
            raise fail(f"--mediapipe-mode must be auto, image or video, got {mediapipe_mode!r}")
        options["running_mode"] = mediapipe_mode
    if detector == "precomputed":
        if predictions is None:
            raise fail("--detector precomputed needs --predictions FILE")
        options["path"] = str(predictions)
    if detector == "hamer":
        if hamer_checkpoint is None or mano_model is None:
            raise fail("--detector hamer needs --hamer-checkpoint PATH and --mano-model PATH (both licensed, not downloaded by demoforge)")
        if box_source not in ("previous", "mediapipe"):
            raise fail(f"--box-source must be previous or mediapipe, got {box_source!r}")
        options.update(checkpoint=str(hamer_checkpoint.resolve()), mano_model=str(mano_model.resolve()), box_source=box_source)
    take = _open_take_or_fail(path)
    try:
        result = run_flow(ingest_take, str(path), str(current_warehouse()), detector=detector, task=task,
                             detector_options=options, state_method=state_method, smoothing=smoothing,
                             video=video, grasp_prior=grasp_prior,
                             table_clearance=None if table_clearance < 0 else table_clearance,
                             accept_bad_depth=accept_bad_depth)
    except (TakeError, ValueError, DetectorError) as e:
        raise fail(str(e))
    for name, m in result.items():
        if m is not None:
            typer.echo(f"{name:<18} {m.rows:>7} rows  {m.path}")
    _echo_hand_presence(result["hand_presence"])
    if result.get("object_keypoints") is None:  # the hand stages stand; the objects wait for annotation
        from lib.annotate import annotation_status, not_annotated_message

        typer.echo(f"warning: object_keypoints: {not_annotated_message(path, annotation_status(take).detail)}", err=True)


def _echo_hand_presence(presence) -> None:
    """The take's per-hand tracking summary (the `hand_presence` table), untrusted hands on stderr."""
    from schemas.core import read_table_file

    for r in [r for f in presence.files for r in read_table_file("hand_presence", f).to_pylist()]:
        line = (f"{r['hand']} hand: detected in {r['frames_detected']} of {r['frames']} frames, "
                f"{r['frames_accepted']} in {r['tracks']} track(s), {r['frames_filled']} filled, "
                f"trajectory on {r['frames_tracked']} frames")
        if r["depth_problem"]:
            line += f"; depth accepted despite `{r['depth_problem']}`"
        if r["trusted"]:
            typer.echo(line + " -- trusted")
        else:
            typer.echo(f"warning: {line} -- NOT TRUSTED: {r['reason']}", err=True)


@app.command()
def augment(
    path: Path = typer.Argument(..., help="Take folder of the demonstration."),
    task: Optional[str] = typer.Option(None, help="Task of the take (synthetic takes know theirs)."),
    detector: str = typer.Option("simulated", "--detector", "-d", help="Detector used to ingest it."),
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
) -> None:
    """Segment an ingested demonstration and generate the task's episode database (thesis 3.2-3.3).

    The episodes come from the take's ingest with the mapping options given here (the same defaults as
    `demoforge ingest`): give the values you ingested with, or the ingest is redone with these."""
    from flows.augment import augment_take_flow
    from lib.annotate import annotation_status, not_annotated_message
    from lib.ingest import TakeError

    status = annotation_status(_open_take_or_fail(path))
    if not status.annotated:  # episodes are placed by the object keypoints: stop before any flow runs
        raise fail(not_annotated_message(path, status.detail))
    options = {"mode": mode, "independent": independent, "yaw_range": [-yaw, yaw]}
    ingest_options = {"state_method": state_method, "smoothing": smoothing, "grasp_prior": grasp_prior,
                      "table_clearance": None if table_clearance < 0 else table_clearance,
                      "accept_bad_depth": accept_bad_depth}
    try:
        result = run_flow(augment_take_flow, str(path), str(current_warehouse()), task=task, detector=detector,
                          n=episodes, n_mirrored=mirrored, seed=seed, options=options, ingest_options=ingest_options,
                          allow_untrusted_hands=allow_untrusted_hands)
    except (TakeError, ValueError) as e:
        raise fail(str(e))
    typer.echo(f"episodes: {result['episodes'].path}")
    from schemas.catalog import query

    t = query("SELECT kind, count(*) AS episodes, count(*) FILTER (WHERE valid) AS valid FROM episodes "
              "WHERE take = ? GROUP BY kind ORDER BY kind", current_warehouse(), [Path(path).resolve().name])
    _emit(t, OutputFormat.table, None, 10)


@app.command()
def retrieve(
    task: str = typer.Option(..., "--task", "-t", help="Task whose episodes to search."),
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

    from flows.augment import read_scene, retrieve as run_retrieve

    try:
        sc = read_scene(scene)
        rows = run_retrieve(str(current_warehouse()), task, sc["object_keypoints"], k=k, strategy=strategy,
                            metric=metric, take=take, seed=seed)
    except ValueError as e:
        raise fail(str(e))
    _emit(pa.Table.from_pylist(rows), format, None, k)


@app.command("evaluate-keypoints")
def evaluate_keypoints_cmd(
    dataset: str = typer.Option("synthetic", "--dataset", help="synthetic (the warehouse's synthetic takes), arctic, or real_photos."),
    detector: Optional[str] = typer.Option(None, "--detector", "-d", help="Default: simulated (synthetic/ARCTIC), mediapipe (real photos)."),
    arctic_root: Optional[Path] = typer.Option(None, "--arctic-root", envvar="ARCTIC_ROOT", help="Where ARCTIC was downloaded."),
    take: Optional[List[str]] = typer.Option(None, "--take", help="Only these takes/sequences (default: the thesis's 18 ARCTIC takes)."),
    subject: Optional[str] = typer.Option(None, help="ARCTIC subject (default: the first that has the sequence)."),
    predictions_dir: Optional[Path] = typer.Option(None, help="For --detector precomputed: one <seq>.parquet/.npz/.json per take."),
    stride: int = typer.Option(1, min=1, help="Evaluate every n-th ARCTIC frame."),
) -> None:
    """Hand-keypoint accuracy as the thesis reports it: Tables 1 and 2, Appendix B, big vs small objects.

    Rows go to `keypoint_metrics` (or `real_photo_metrics`); the tables are the SQL views report_table1,
    report_table2, report_appendix_b, report_big_vs_small and report_real_photos.
    """
    from flows.keypoint_eval import evaluate_keypoints
    from lib.arctic import ArcticError

    try:
        run_flow(evaluate_keypoints, str(current_warehouse()), dataset=dataset, detector=detector,
                           arctic_root=str(arctic_root) if arctic_root else None, takes=take or None,
                           subject=subject, predictions_dir=str(predictions_dir) if predictions_dir else None,
                           stride=stride)
    except (ArcticError, ValueError, FileNotFoundError) as e:
        raise fail(str(e))
    from schemas.catalog import query

    view = "report_real_photos" if dataset == "real_photos" else "report_table1"
    _emit(query(f"SELECT * FROM {view}", current_warehouse()), OutputFormat.table, None, 40)


@app.command("evaluate-detection")
def evaluate_detection_cmd(
    detector: str = typer.Option("mediapipe", "--detector", "-d", help="A real detector: mediapipe."),
    mode: Optional[List[str]] = typer.Option(None, "--mode", help="MediaPipe running mode(s), repeatable: auto (video mode for takes; default) or image."),
    take: Optional[List[str]] = typer.Option(None, "--take", help="Only these synthetic takes (default: all in the warehouse)."),
) -> None:
    """Hand detection against the synthetic takes' ground truth, per task: detection rate over
    hand-frames with >= 80 % of the joints in view, handedness accuracy, 2D MPJPE (px), PCK@0.05/0.15,
    and the same where a held object hides part of the hand. Rows go to `detection_metrics`."""
    from flows.detection_eval import evaluate_detection
    from lib.detectors import DetectorError
    from lib.evaluation.detection import per_task
    from schemas.catalog import query

    modes = mode or ["auto"]
    bad = [m for m in modes if m not in ("auto", "image", "video")]
    if bad:
        raise fail(f"--mode must be auto, image or video, got {bad[0]!r}")
    try:
        have = query("SELECT count(*) AS n FROM takes WHERE source = 'synthetic'", current_warehouse()).to_pylist()
    except Exception:  # noqa: BLE001 - no takes table yet
        have = [{"n": 0}]
    if not have or not have[0]["n"]:
        raise fail("no synthetic takes in the warehouse: run `demoforge synth` first")
    try:
        run_flow(evaluate_detection, str(current_warehouse()), detector=detector, running_modes=modes,
                 takes=take or None)
    except (DetectorError, ValueError, FileNotFoundError) as e:
        raise fail(str(e))
    rows = query("SELECT * FROM detection_metrics", current_warehouse()).to_pylist()
    wanted = {"video" if m == "auto" else m for m in modes}
    rows = [r for r in rows if r["detector"] == detector and r["running_mode"] in wanted
            and (not take or r["take"] in take)]
    from lib.evaluation.detection import format_markdown

    typer.echo(format_markdown(per_task(rows)))


@app.command("llm-eval")
def llm_eval_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episode database provides the examples."),
    strategy: Optional[List[str]] = typer.Option(None, "--strategy", "-s", help="single, random, retrieval, replay_top1, transform_demo (repeatable; default all)."),
    backend: str = typer.Option("local", envvar="LLM_BACKEND", help="local (Gemma 3 270M via llama.cpp, offline) or openai (OPENAI_BASE_URL, OPENAI_API_KEY, DEMOFORGE_LLM_MODEL)."),
    model: Optional[str] = typer.Option(None, envvar="LLM_MODEL", help="Model name for the openai backend."),
    trials: int = typer.Option(3, envvar="TRIALS", min=1, help="Query scenes per take and strategy (the thesis: 10)."),
    seed: int = typer.Option(0, help="Seed of the query scenes and of the random strategy."),
    waypoints: int = typer.Option(20, help="Waypoints per example action sequence in the prompt."),
    precision: int = typer.Option(3, help="Decimals of the numbers in the prompt."),
) -> None:
    """Predict trajectories with an LLM for new scenes and judge them in MuJoCo (thesis Table 3)."""
    from flows.llm_eval import ALL_STRATEGIES, llm_eval

    options = {"model": model} if model else {}
    try:
        run_flow(llm_eval, str(current_warehouse()), task=task, strategies=strategy or list(ALL_STRATEGIES), backend=backend,
                 backend_options=options, trials=trials, seed=seed, n_waypoints=waypoints, precision=precision)
    except ValueError as e:
        raise fail(str(e))
    from schemas.catalog import query

    _emit(query("SELECT * FROM report_table3 WHERE task = ?", current_warehouse(), [task]), OutputFormat.table, None, 40)


def _episodes_option(episodes: str) -> int | str:
    """--episodes of simulate / stability: a count or `all`."""
    if episodes == "all":
        return episodes
    if not episodes.isdigit():
        raise fail(f"--episodes must be a number or 'all', got {episodes!r}")
    return int(episodes)


@app.command()
def simulate(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episodes to check."),
    episodes: str = typer.Option("100", "--episodes", "-n", help="How many (the original first, then a seeded sample of valid ones), or `all`."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); default: the task's first."),
    workers: int = typer.Option(2, min=1, help="Worker processes."),
    chunk_size: int = typer.Option(100, min=1, help="Episodes per cached chunk (a crash loses at most one chunk)."),
    seed: int = typer.Option(0, help="Seed of the episode sample."),
) -> None:
    """Execute episodes with two parallel-jaw grippers in MuJoCo physics and record success and failure reasons."""
    from flows.sim import simulate_episodes

    n = _episodes_option(episodes)
    try:
        run_flow(simulate_episodes, str(current_warehouse()), task=task, episodes=n, take=take, chunk_size=chunk_size,
                          workers=workers, seed=seed)
    except ValueError as e:
        raise fail(str(e))
    from schemas.catalog import query

    wh = current_warehouse()
    result = query("SELECT * FROM report_sim WHERE task = ?", wh, [task])
    _emit(result, OutputFormat.table, None, 40)
    if sum(result.column("successes").to_pylist()) < sum(result.column("episodes").to_pylist()):
        typer.echo(f"Why: demoforge sql \"SELECT * FROM report_sim_failures WHERE task = '{task}'\". Whether a "
                   f"failure is the trajectory's or chance: demoforge stability --task {task}")


@app.command()
def stability(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episodes to check."),
    episodes: str = typer.Option("40", "--episodes", "-n", help="How many (the original first, then a seeded sample of valid ones), or `all`."),
    repeats: int = typer.Option(5, min=2, help="Executions per episode: the scene as it is, then repeats - 1 shifted copies."),
    jitter: float = typer.Option(1e-4, help="Standard deviation of the rigid shift of the whole scene along the table, in metres "
                                 "(default 0.1 mm: physically nothing; only the simulation's rounding changes)."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); default: the task's first."),
    workers: int = typer.Option(2, min=1, help="Worker processes."),
    chunk_size: int = typer.Option(20, min=1, help="Episodes per cached chunk (each executed `repeats` times)."),
    seed: int = typer.Option(0, help="Seed of the episode sample and of the shifts."),
) -> None:
    """Check how stable the robot check's verdicts are: execute each episode several times with the whole
    scene shifted by a fraction of a millimetre. An episode whose outcome flips is decided by numerical chaos, not by its
    trajectory; its success is a probability. Rows: `sim_stability`; summary: `report_sim_stability`."""
    from flows.sim import check_stability

    n = _episodes_option(episodes)
    try:
        run_flow(check_stability, str(current_warehouse()), task=task, episodes=n, repeats=repeats, jitter_m=jitter,
                 take=take, chunk_size=chunk_size, workers=workers, seed=seed)
    except ValueError as e:
        raise fail(str(e))
    from schemas.catalog import query

    _emit(query("SELECT * FROM report_sim_stability WHERE task = ?", current_warehouse(), [task]), OutputFormat.table, None, 40)


@app.command("render-episode")
def render_episode_cmd(
    task: str = typer.Option(..., "--task", "-t"),
    episode: int = typer.Option(..., "--episode", "-e", help="Episode id (see the `episodes` table)."),
    out: Path = typer.Option(Path("episode.mp4"), "--out", "-o", help="Output MP4."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take)."),
) -> None:
    """Render an offscreen video of the robot executing one episode."""
    from flows.sim import render_episode_video

    try:
        row = render_episode_video(str(current_warehouse()), task, episode, out, take=take)
    except ValueError as e:
        raise fail(str(e))
    typer.echo(f"{out}: {'success' if row['success'] else 'failed: ' + str(row['failure'])} ({row['detail']})")


@app.command("ingest-folder")
def ingest_folder_cmd(
    folder: Path = typer.Argument(..., help="Folder whose take folders (any folder with camera.json) to ingest."),
    detector: str = typer.Option("simulated", "--detector", "-d", help="simulated (synthetic takes), mediapipe, precomputed."),
    task: Optional[str] = typer.Option(None, help="Task of the takes (synthetic takes know theirs)."),
    augment: bool = typer.Option(False, "--augment", help="Also generate each take's episode database."),
    episodes: int = typer.Option(10_000, "--episodes", "-n", min=1, help="Episodes per take with --augment."),
) -> None:
    """Ingest every take under a folder; a take that fails is recorded in `folder_ingests` and skipped.

    This is the flow of the scheduled deployment (`demoforge serve`)."""
    from flows.ingest import ingest_folder

    if not folder.is_dir():  # before the flow starts: one line, no flow-run traceback
        raise fail(f"{folder}: no such folder to ingest takes from")
    try:
        rows = run_flow(ingest_folder, str(folder), str(current_warehouse()), detector=detector, task=task,
                        augment=augment, episodes=episodes)
    except ValueError as e:
        raise fail(str(e))
    for r in rows:
        typer.echo(f"{r['status']:<16} {r['take']}  {r['error']}")
    if not rows:
        typer.echo(f"no take folders (folders with camera.json) under {folder}")


@app.command()
def serve(
    inbox: Path = typer.Option(Path("takes/inbox"), help="Folder the scheduled deployment ingests takes from (created if missing)."),
    every: float = typer.Option(10.0, "--every", help="Minutes between scheduled ingests of the inbox."),
    reports: Path = typer.Option(Path("reports"), "--reports", help="Report folder of the evaluate deployment."),
    detector: str = typer.Option("simulated", "--detector", "-d", help="Detector of the scheduled ingest."),
    augment: bool = typer.Option(False, "--augment", help="Scheduled ingest also generates episode databases."),
    limit: int = typer.Option(1, min=1, help="Flow runs executed at the same time."),
) -> None:
    """Serve the Prefect deployments `ingest-folder/scheduled` and `evaluate/default` until Ctrl-C.

    Needs a Prefect server: `prefect server start` in another shell and PREFECT_API_URL pointing at it.
    Then trigger runs with `prefect deployment run 'evaluate/default' --watch`."""
    import os

    from flows.deployments import serve_deployments

    if not os.environ.get("PREFECT_API_URL"):
        raise fail("PREFECT_API_URL is not set: start a server (`prefect server start --host 127.0.0.1 --port 4200`) "
                   "and export PREFECT_API_URL=http://127.0.0.1:4200/api, so the deployments outlive this process")
    try:
        serve_deployments(str(current_warehouse()), str(inbox), str(reports), interval_minutes=every,
                          detector=detector, augment=augment, limit=limit)
    except ValueError as e:
        raise fail(str(e))


# Commands of the larger areas live in their own modules and register on `app` when imported.
from flows import cli_export, cli_hamer, cli_policy, cli_table3, cli_variations  # noqa: E402,F401


def main() -> None:
    app()


if __name__ == "__main__":
    main()
