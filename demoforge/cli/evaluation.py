"""`demoforge evaluate-keypoints`, `evaluate-detection`, `llm-eval`: measuring the stages."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional
import typer

from demoforge.runtime.runners import run_flow
from demoforge.cli.warehouse import OutputFormat, _emit
from demoforge.cli.root import (TASK_HELP, api_mode_option, base_url_option, current_warehouse, detector_option, fail,
                                llm_backend_option, llm_backend_options, number_format_option, structured_option,
                                waypoints_option)

app = typer.Typer()


@app.command("evaluate-keypoints")
def evaluate_keypoints_cmd(
    dataset: str = typer.Option("synthetic", "--dataset", help="synthetic (the warehouse's synthetic takes), arctic, or real_photos."),
    detector: Optional[str] = detector_option(None, help="Default: simulated (synthetic/ARCTIC), mediapipe (real photos)."),
    arctic_root: Optional[Path] = typer.Option(None, "--arctic-root", envvar="DEMOFORGE_ARCTIC_ROOT", help="Where ARCTIC was downloaded."),
    take: Optional[List[str]] = typer.Option(None, "--take", help="Only these takes/sequences (default: the thesis's 18 ARCTIC takes)."),
    subject: Optional[str] = typer.Option(None, help="ARCTIC subject (default: the first that has the sequence)."),
    predictions_dir: Optional[Path] = typer.Option(None, help="For --detector precomputed: one <seq>.parquet/.npz/.json per take."),
    stride: int = typer.Option(1, min=1, help="Evaluate every n-th ARCTIC frame."),
) -> None:
    """Hand-keypoint accuracy as the thesis reports it: Tables 1 and 2, Appendix B, big vs small objects.

    Rows go to `keypoint_metrics` (or `real_photo_metrics`); the tables are the SQL views report_table1,
    report_table2, report_appendix_b, report_big_vs_small and report_real_photos.
    """
    from demoforge.flows.keypoint_eval import evaluate_keypoints  # lazy: prefect
    from demoforge.lib.evaluation.arctic import ArcticError  # lazy (CLI start-up): numpy

    try:
        run_flow(evaluate_keypoints, str(current_warehouse()), dataset=dataset, detector=detector,
                           arctic_root=str(arctic_root) if arctic_root else None, takes=take or None,
                           subject=subject, predictions_dir=str(predictions_dir) if predictions_dir else None,
                           stride=stride)
    except (ArcticError, ValueError, FileNotFoundError) as e:
        raise fail(str(e))
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    view = "report_real_photos" if dataset == "real_photos" else "report_table1"
    _emit(query(f"SELECT * FROM {view}", current_warehouse()), OutputFormat.table, None, 40)


@app.command("evaluate-detection")
def evaluate_detection_cmd(
    detector: str = detector_option("mediapipe", help="A real detector: mediapipe."),
    mode: Optional[List[str]] = typer.Option(None, "--mode", help="MediaPipe running mode(s), repeatable: auto (video mode for takes; default) or image."),
    take: Optional[List[str]] = typer.Option(None, "--take", help="Only these synthetic takes (default: all in the warehouse)."),
) -> None:
    """Hand detection against the synthetic takes' ground truth, per task: detection rate over
    hand-frames with >= 80 % of the joints in view, handedness accuracy, 2D MPJPE (px), PCK@0.05/0.15,
    and the same where a held object hides part of the hand. Rows go to `detection_metrics`."""
    from demoforge.flows.detection_eval import evaluate_detection  # lazy: prefect
    # lazy (CLI start-up): duckdb, numpy, pyarrow, scipy
    from demoforge.lib.perception.detectors import DetectorError
    from demoforge.lib.evaluation.detection import per_task
    from demoforge.schemas.catalog import query

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
    from demoforge.lib.evaluation.detection import format_markdown  # lazy (CLI start-up): numpy, scipy

    typer.echo(format_markdown(per_task(rows)))


@app.command("llm-eval")
def llm_eval_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episode database provides the examples. " + TASK_HELP),
    strategy: Optional[List[str]] = typer.Option(None, "--strategy", "-s", help="single, random, retrieval, replay_top1, transform_demo (repeatable; default all)."),
    backend: str = llm_backend_option(),
    model: Optional[str] = typer.Option(None, envvar="DEMOFORGE_LLM_MODEL", help="Model name for the openai backend."),
    trials: int = typer.Option(3, envvar="DEMOFORGE_TRIALS", min=1, help="Query scenes per take and strategy (the thesis: 10)."),
    seed: int = typer.Option(0, help="Seed of the query scenes and of the random strategy."),
    waypoints: Optional[int] = waypoints_option(),
    precision: int = typer.Option(3, help="Decimals of the numbers in the prompt."),
    structured: Optional[bool] = structured_option(),
    base_url: Optional[str] = base_url_option(),
    api_mode: str = api_mode_option(),
    number_format: Optional[str] = number_format_option(),
) -> None:
    """Predict trajectories with an LLM for new scenes and judge them in MuJoCo (thesis Table 3)."""
    from demoforge.flows.llm_eval import ALL_STRATEGIES, llm_eval  # lazy: prefect

    options = llm_backend_options(backend, model, base_url, api_mode)
    try:
        run_flow(llm_eval, str(current_warehouse()), task=task, strategies=strategy or list(ALL_STRATEGIES), backend=backend,
                 backend_options=options, trials=trials, seed=seed, n_waypoints=waypoints, precision=precision, structured=structured,
                 number_format=number_format)
    except ValueError as e:
        raise fail(str(e))
    from demoforge.schemas.catalog import query  # lazy (CLI start-up): duckdb, pyarrow

    _emit(query("SELECT * FROM report_table3 WHERE task = ?", current_warehouse(), [task]), OutputFormat.table, None, 40)
