"""Flow: a real hand detector measured against the synthetic takes' ground truth, per task."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.schemas.catalog import query
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.detection_eval import evaluate_detection_take


@flow(name="evaluate-detection")
def evaluate_detection(warehouse: str, detector: str = "mediapipe",
                       running_modes: Sequence[str] = ("auto",), takes: list[str] | None = None) -> list[Manifest]:
    """Write `detection_metrics` for every synthetic take in the warehouse (or `takes`), once per
    running mode ("auto" = video mode for takes, "image")."""
    logger = get_run_logger()
    rows = query("SELECT path FROM takes WHERE source = 'synthetic' ORDER BY take", warehouse).to_pylist()
    paths = [r["path"] for r in rows if takes is None or Path(r["path"]).name in takes]
    if not paths:
        raise ValueError("no synthetic takes in the warehouse: run `demoforge synth` first")
    out = []
    for mode in running_modes:
        if mode not in ("auto", "image", "video"):
            raise ValueError(f"running mode must be auto, image or video, got {mode!r}")
        for p in paths:
            out.append(run_stage(evaluate_detection_take, warehouse, take_dir=Path(p), warehouse=warehouse,
                                 detector=detector, running_mode=mode))
            logger.info("detection on %s (%s) evaluated", Path(p).name, mode)
    return out
