"""Prefect tasks of the hand-keypoint evaluation (thesis 4.2): one take or one photo set per call."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.evaluation.arctic import ArcticDataset
from demoforge.lib.evaluation.keypoints import (evaluate_arctic_take, evaluate_real_photos as run,
                                                evaluate_synthetic_take)
from demoforge.lib.perception.detectors import HandTrack, get_detector, select_best_hands
from demoforge.lib.perception.simulated_detector import simulate_detections
from demoforge.schemas.core import get_schema, write_table
from demoforge.tasks.common import Manifest, stage_task

EVAL_VERSION = "1"


def _write_rows(table: str, rows: list[dict], warehouse: str) -> Manifest:
    """Rows (dicts with possibly extra keys) -> the table's columns only."""
    cols = [c.name for c in get_schema(table).columns]
    data = {c: [r.get(c) for r in rows] for c in cols}
    for c in get_schema(table).columns:  # NaN-free strings and ints; metrics stay NaN/None
        if c.type == pa.string():
            data[c.name] = ["" if v is None else str(v) for v in data[c.name]]
    written = write_table(table, data, warehouse)
    return Manifest.from_written(table, written)


@stage_task(name="evaluate_synthetic_keypoints", version=EVAL_VERSION)
def evaluate_synthetic_keypoints(take_dir: Path, warehouse: str, detector: str = "simulated") -> Manifest:
    """The thesis's keypoint metrics of one synthetic take (depth alignment on its rendered depth)."""
    rows = evaluate_synthetic_take(take_dir, detector=detector)
    for r in rows:
        r.update(dataset="synthetic", take=take_dir.name, subject="")
    return _write_rows("keypoint_metrics", rows, warehouse)


@stage_task(name="evaluate_arctic_keypoints", version=EVAL_VERSION)
def evaluate_arctic_keypoints(arctic_root: str, seq: str, subject: str | None, warehouse: str,
                              detector: str = "simulated", predictions_dir: str | None = None,
                              stride: int = 1) -> Manifest:
    """One ARCTIC take (egocentric view 0): run the detector on its frames, evaluate against ARCTIC.

    ARCTIC has no depth camera: the alignment reads the anchor's depth from the ground truth."""
    ds = ArcticDataset(arctic_root)
    take = ds.load(subject, seq, view=0, stride=stride, require_images=detector == "mediapipe")
    track = _detect_arctic(take, detector, predictions_dir)
    rows = evaluate_arctic_take(take, track, detector=track.detector, detector_version=track.detector_version)
    for r in rows:
        r.update(dataset="arctic", take=seq)
    return _write_rows("keypoint_metrics", rows, warehouse)


def _detect_arctic(take, detector: str, predictions_dir: str | None):
    T = len(take.frame_indices)
    if detector == "simulated":
        K = take.K if np.ndim(take.K) == 2 else take.K[0]
        gt = np.where(take.valid[..., None, None], take.joints_cam, np.nan)
        sim = simulate_detections(gt, K, seed=0)
        return HandTrack(sim.joints_cam, sim.joints_px, sim.confidence, sim.present,
                         sim.present.astype(np.int64), detector="simulated", detector_version="error model 1")
    if detector == "precomputed":
        if not predictions_dir:
            raise ValueError("detector 'precomputed' needs predictions_dir with one <seq>.parquet/.npz/.json per take")
        files = [p for p in Path(predictions_dir).glob(f"{take.seq}.*") if p.suffix in (".parquet", ".npz", ".json")]
        if not files:
            raise FileNotFoundError(f"no predictions for {take.seq} in {predictions_dir} (<seq>.parquet/.npz/.json)")
        det = get_detector("precomputed", path=files[0], K=take.K if np.ndim(take.K) == 2 else take.K[0])
        by_frame = det.candidates()  # keyed by the sequence's frame index
        return select_best_hands({i: by_frame.get(int(f), []) for i, f in enumerate(take.frame_indices)}, T,
                                 detector=det.name, detector_version=det.version)
    if detector == "mediapipe":
        import cv2

        det = get_detector("mediapipe")
        cands = []
        try:
            for i, path in enumerate(take.image_paths):
                rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
                K = take.K if np.ndim(take.K) == 2 else take.K[i]
                cands += det.detect(rgb[None], K, [i])
        finally:
            det.close()
        return select_best_hands(cands, T, detector=det.name, detector_version=det.version)
    raise ValueError(f"unknown detector {detector!r} for ARCTIC: simulated, mediapipe or precomputed")


@stage_task(name="evaluate_real_photos", version=EVAL_VERSION)
def evaluate_real_photos(data_dir: Path, warehouse: str, detector: str = "mediapipe") -> Manifest:
    """The detector on the labelled real hand photos, per dataset."""
    if detector != "mediapipe":
        raise ValueError("the real-photo evaluation runs the mediapipe detector (the other backends need "
                         "ground truth or precomputed predictions)")
    rows = run(data_dir=data_dir)
    return _write_rows("real_photo_metrics", rows, warehouse)
