"""Flow: hand-keypoint accuracy (thesis Tables 1, 2 and Appendix B) on ARCTIC, synthetic takes or real photos."""

from __future__ import annotations

from pathlib import Path

from prefect import flow, get_run_logger

import demoforge.lib  # SHARED_DATA
from demoforge.lib.evaluation.arctic import THESIS_TAKES
from demoforge.schemas.catalog import query
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.keypoint_eval import (
    evaluate_arctic_keypoints, evaluate_real_photos, evaluate_synthetic_keypoints,
)

REAL_HANDS = demoforge.lib.SHARED_DATA / "real_hands"


@flow(name="evaluate-keypoints")
def evaluate_keypoints(
    warehouse: str,
    dataset: str = "synthetic",
    detector: str | None = None,
    arctic_root: str | None = None,
    takes: list[str] | None = None,
    subject: str | None = None,
    predictions_dir: str | None = None,
    stride: int = 1,
    real_photos_dir: str | None = None,
) -> list[Manifest]:
    """Write `keypoint_metrics` (or `real_photo_metrics`) for one dataset.

    dataset: `synthetic` (every synthetic take in the warehouse; detector `simulated`), `arctic`
    (the thesis's 18 takes under `arctic_root`, or `takes`; detector `simulated` (ARCTIC's ground
    truth through the simulated error model), `mediapipe`, or `precomputed` with `predictions_dir`
    holding one <seq>.parquet/.npz/.json per take), or `real_photos` (mediapipe on the labelled
    photos of ../shared/data/real_hands).
    """
    logger = get_run_logger()
    out = []
    if dataset == "synthetic":
        rows = query("SELECT path FROM takes WHERE source = 'synthetic' ORDER BY take", warehouse).to_pylist()
        paths = [r["path"] for r in rows if takes is None or Path(r["path"]).name in takes]
        if not paths:
            raise ValueError("no synthetic takes in the warehouse: run `demoforge synth` first")
        for p in paths:
            out.append(run_stage(evaluate_synthetic_keypoints, warehouse, take_dir=Path(p), warehouse=warehouse,
                                 detector=detector or "simulated"))
    elif dataset == "arctic":
        if not arctic_root:
            raise ValueError("dataset 'arctic' needs --arctic-root (or ARCTIC_ROOT): the folder you downloaded ARCTIC to")
        for seq in takes or list(THESIS_TAKES):
            out.append(run_stage(evaluate_arctic_keypoints, warehouse, arctic_root=str(Path(arctic_root).resolve()),
                                 seq=seq, subject=subject, warehouse=warehouse, detector=detector or "simulated",
                                 predictions_dir=predictions_dir, stride=stride))
            logger.info("ARCTIC %s evaluated", seq)
    elif dataset == "real_photos":
        data = Path(real_photos_dir) if real_photos_dir else REAL_HANDS
        if not data.is_dir():
            raise ValueError(f"{data}: the labelled real hand photos are missing (../shared/data/real_hands)")
        out.append(run_stage(evaluate_real_photos, warehouse, data_dir=data, warehouse=warehouse,
                             detector=detector or "mediapipe"))
    else:
        raise ValueError(f"unknown dataset {dataset!r}: synthetic, arctic or real_photos")
    return out
