"""The main job (`make evaluate`): default synthetic takes -> every flow -> reports/."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from flows.report import write_report
from flows.synth import synthesize_takes


@flow(name="evaluate")
def evaluate(
    warehouse: str,
    reports_dir: str,
    tasks: Sequence[str] | None = None,
    takes: int = 1,
    seed: int = 0,
    mirror: str = "both",
) -> str:
    """Generate the default synthetic takes (all six tasks, original and mirrored), run every stage
    on them and write reports/REPORT.md. Everything already computed comes from the cache."""
    from lib.task_library import TASK_NAMES

    logger = get_run_logger()
    tasks = list(tasks) if tasks else list(TASK_NAMES)
    synthesize_takes(warehouse, tasks=tasks, takes=takes, seed=seed, mirror=mirror)
    report = write_report(warehouse, reports_dir,
                          {"tasks": tasks, "takes": takes, "seed": seed, "mirror": mirror})
    logger.info("report written: %s", report)
    return str(report)
