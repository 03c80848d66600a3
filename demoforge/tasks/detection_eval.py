"""Prefect task of the detection evaluation: one synthetic take, one detector, one running mode."""

from __future__ import annotations

from pathlib import Path

from demoforge.lib.evaluation.detection import evaluate_detection
from demoforge.tasks.common import Manifest, stage_task
from demoforge.tasks.keypoint_eval import _write_rows

DETECTION_EVAL_VERSION = "1"


@stage_task(name="evaluate_detection", version=DETECTION_EVAL_VERSION)
def evaluate_detection_take(take_dir: Path, warehouse: str, detector: str = "mediapipe",
                            running_mode: str = "auto") -> Manifest:
    """`detection_metrics` rows (subsets all, occluded) of one take (demoforge.lib.evaluation.detection)."""
    opts = {"running_mode": running_mode} if detector == "mediapipe" else {}
    rows = evaluate_detection(take_dir, detector, **opts)
    return _write_rows("detection_metrics", rows, warehouse)
