"""Prefect deployments of demoforge, served by one long-running process (`demoforge serve`).

- `ingest-folder/scheduled`: every `interval_minutes`, ingest the take folders that appeared in the
  inbox folder (already ingested takes come from the cache; failures land in `folder_ingests`).
- `evaluate/default`: the main job (`make evaluate`), on demand.

Start a server, serve, trigger:

    prefect server start --host 127.0.0.1 --port 4200 --analytics-off &
    export PREFECT_API_URL=http://127.0.0.1:4200/api
    demoforge serve --inbox takes/inbox &
    prefect deployment run 'ingest-folder/scheduled' --param folder=takes/other --watch
    prefect deployment run 'evaluate/default' --param sim_episodes=40 --watch

Flow runs execute in subprocesses of the serving process, so they see its environment (warehouse,
task runner configuration).
"""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

INGEST_DEPLOYMENT = "ingest-folder/scheduled"
EVALUATE_DEPLOYMENT = "evaluate/default"


def build_deployments(warehouse: str, inbox: str, reports_dir: str, interval_minutes: float = 10.0,
                      detector: str = "simulated", augment: bool = False):
    """The two deployments, with absolute paths baked into their default parameters."""
    # lazy: mujoco, prefect
    from demoforge.flows.evaluate import evaluate
    from demoforge.flows.ingest_folder import ingest_folder

    if interval_minutes <= 0:
        raise ValueError(f"the ingest interval must be positive minutes, got {interval_minutes}")
    warehouse = str(Path(warehouse).resolve())
    ingest = ingest_folder.to_deployment(
        name=INGEST_DEPLOYMENT.split("/")[1],
        interval=timedelta(minutes=interval_minutes),
        parameters={"folder": str(Path(inbox).resolve()), "warehouse": warehouse, "ingest": {"detector": detector},
                    "augment": {"n": 10_000, "n_mirrored": 5_000} if augment else None},
        description="Ingest the take folders in the inbox (new or changed ones; the rest is cached).",
        tags=["demoforge", "ingest"],
    )
    main_job = evaluate.to_deployment(
        name=EVALUATE_DEPLOYMENT.split("/")[1],
        parameters={"warehouse": warehouse, "reports_dir": str(Path(reports_dir).resolve())},
        description="The main job: synthetic takes -> every flow -> reports/REPORT.md.",
        tags=["demoforge", "evaluate"],
    )
    return [ingest, main_job]


def serve_deployments(warehouse: str, inbox: str, reports_dir: str, interval_minutes: float = 10.0,
                      detector: str = "simulated", augment: bool = False, limit: int | None = 1) -> None:
    """Register the deployments with the Prefect API and run their flow runs until interrupted.

    `limit` caps concurrent flow runs (one at a time by default: the stages are CPU-bound)."""
    from prefect import serve

    Path(inbox).mkdir(parents=True, exist_ok=True)
    serve(*build_deployments(warehouse, inbox, reports_dir, interval_minutes, detector, augment), limit=limit)
