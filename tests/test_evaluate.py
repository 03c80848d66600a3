"""The main job end to end on one task: every stage, the report, and a second run from the cache."""

import csv as csv_module
from pathlib import Path

import pytest

from demoforge.flows.evaluate import detector_problem, evaluate
from demoforge.lib.evaluation.config import EvaluateConfig
from tests.conftest import SHARED_DATA, require_mediapipe_model

pytestmark = pytest.mark.slow

HAVE_PHOTOS = (SHARED_DATA / "real_hands").is_dir()


def test_evaluate_writes_the_report_and_reruns_from_cache(prefect_api, warehouse, tmp_path, monkeypatch):
    if HAVE_PHOTOS:  # the main job runs the MediaPipe detector on the photos when they are there
        require_mediapipe_model()
    have_mediapipe = detector_problem("mediapipe") is None  # else the main job leaves it out (warned)
    reports = tmp_path / "reports"
    out = Path(evaluate(str(warehouse), str(reports), EvaluateConfig(tasks=("paper_in_case",), mirror="no", episodes=300)))
    text = out.read_text()
    for heading in ("## Takes", "## Scripted demonstrations in physics", "## Ingest accuracy per task",
                    "## Segmentation against the scripted boundaries", "## Augmented episodes",
                    "## Table 1: MPJPE and PA-MPJPE (m) — synthetic, by detector",
                    "## Robot success on the ingested demonstrations, per detector",
                    "## Table 2: 2D MPJPE (px) and PCK", "## Appendix B: per take",
                    "## A real detector on labelled real photos", "## How stable the robot check's verdicts are"):
        assert heading in text
    assert "synth_paper_in_case_s0000" in text and "simulated" in text
    assert "![synthetic takes](synthetic_takes.png)" in text and (reports / "synthetic_takes.png").stat().st_size > 10_000
    assert (reports / "keypoints_per_take_synthetic_simulated.png").stat().st_size > 5_000
    for csv in ("report_takes", "report_ingest_accuracy", "report_augmentation", "report_segmentation",
                "report_table1_synthetic", "report_ingested_demos") + (("report_real_photos",) if HAVE_PHOTOS else ()):
        lines = (reports / f"{csv}.csv").read_text().splitlines()
        assert len(lines) >= 2, csv
    stability = (reports / "report_sim_stability.csv").read_text().splitlines()
    assert len(stability) == 2 and "sample-10-seed0-r3-j0.0001-s0" in stability[1]
    # the detectors side by side: every table of the ingest's accuracy, Tables 1 and 2, the robot's check
    detectors = ["simulated", "mediapipe"] if have_mediapipe else ["simulated"]
    for csv, rows_per_detector in (("report_ingest_by_task", 1), ("report_ingest_accuracy", 2),
                                   ("report_table1_synthetic", 4), ("report_table2_synthetic", 2),
                                   ("report_ingested_demos", 1)):
        found = [r["detector"] for r in csv_module.DictReader((reports / f"{csv}.csv").open())]
        assert sorted(found) == sorted(d for d in detectors for _ in range(rows_per_detector)), (csv, found)
    if have_mediapipe:
        assert (reports / "keypoints_per_take_synthetic_mediapipe.png").stat().st_size > 5_000
    aug = (reports / "report_augmentation.csv").read_text()
    assert '"original"' in aug and '"mirrored"' in aug and '"translated"' in aug

    def must_not_run(*a, **k):
        raise AssertionError("a cached stage ran again")

    for target in ("demoforge.lib.synth.take.generate_take", "demoforge.lib.perception.detectors.get_detector",
                   "demoforge.lib.ingest.alignment.align_to_depth", "demoforge.lib.trajectories.augmentation.generate_episodes"):
        monkeypatch.setattr(target, must_not_run)
    again = Path(evaluate(str(warehouse), str(reports), EvaluateConfig(tasks=("paper_in_case",), mirror="no", episodes=300)))
    assert again == out and "synth_paper_in_case_s0000" in again.read_text()
