"""Prefect tasks that measure an ingested synthetic take against its ground truth: the ingest's errors per
hand (`ingest_metrics`) and the thesis's keypoint metrics of the ingest's own detections
(`keypoint_metrics`, dataset `synthetic`). A take without ground truth gives None."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from demoforge.lib.evaluation import metrics as M
from demoforge.lib.evaluation.keypoints import evaluate_take, load_synth_ground_truth
from demoforge.lib.ingest.alignment import AlignmentConfig, read_depth_robust
from demoforge.lib.ingest.depth_checks import depth_coverage
from demoforge.lib.takes import iter_depth, take_task_name
from demoforge.schemas.core import get_schema, read_table, read_table_file, write_table
from demoforge.schemas.reads.per_hand import HANDS, arrays
from demoforge.tasks.common import Manifest, opened_take, stage_task
from demoforge.tasks.ingest import INGEST_VERSION


@stage_task(name="ingest_metrics", version=f"{INGEST_VERSION}/depth-coverage-1", key_optional=("variant",))
def ingest_metrics(take_dir: Path, task: str | None, warehouse: str, hand_keypoints: Manifest,
                   aligned: Manifest, grippers: Manifest, variant: dict | None = None) -> Manifest | None:
    """Per hand: keypoint errors before/after alignment, gripper errors, open/close accuracy, swaps, the
    share without depth at the hand."""
    take = opened_take(take_dir)
    if not take.has_ground_truth:
        return None
    name = take_task_name(take, task)
    part = dict(task=name, take=take.take_id, variant=variant)
    _, raw = arrays(read_table("hand_keypoints", warehouse, **part), "joints_cam", "joints_px", "present")
    al_t = read_table("aligned_keypoints", warehouse, **part)
    _, al = arrays(al_t, "joints_cam", "detected", "swap_repaired", "no_depth")
    coverage = depth_coverage(al["detected"], al["no_depth"])
    _, gp = arrays(read_table("gripper_poses", warehouse, **part), "pose", "g_threshold", "g_auto", "g_manual")
    gt_dir = take.ground_truth_dir
    _, gt = arrays(read_table_file("gt_hand_joints", gt_dir / "gt_hand_joints.parquet"),
                   "joints_camera", "joints_px", "present")
    _, gg = arrays(read_table_file("gt_gripper", gt_dir / "gt_gripper.parquet"), "pose", "closed")
    detector = al_t.column("detector")[0].as_py()
    g_true = 1.0 - gg["closed"].astype(float)

    diag = Path(warehouse) / "_diagnostics" / "detector" / f"{take.take_id}.{detector}.npz"
    injected = np.load(diag)["injected_swap"] if diag.exists() else np.zeros(len(g_true), bool)
    repaired = al["swap_repaired"].any(axis=1)
    out = []
    for h, hand in enumerate(HANDS):
        in_view = gt["present"][:, h]
        det = in_view & raw["present"][:, h]
        aligned_ok = in_view & al["detected"][:, h]  # frozen/filled frames are not measurements
        g_man = gp["g_manual"][:, h]
        out.append({
            "take": take.take_id, "task": name, "detector": detector, "hand": hand,
            "frames": int(in_view.sum()),
            "detected_fraction": float(det.sum() / max(in_view.sum(), 1)),
            "mpjpe_raw_m": M.mpjpe(raw["joints_cam"][det, h], gt["joints_camera"][det, h]),
            "mpjpe_aligned_m": M.mpjpe(al["joints_cam"][aligned_ok, h], gt["joints_camera"][aligned_ok, h]),
            "pa_mpjpe_m": M.pa_mpjpe(al["joints_cam"][aligned_ok, h], gt["joints_camera"][aligned_ok, h]),
            "root_relative_mpjpe_m": M.root_relative_mpjpe(al["joints_cam"][aligned_ok, h], gt["joints_camera"][aligned_ok, h]),
            "mpjpe_2d_px": M.mpjpe_2d(raw["joints_px"][det, h], gt["joints_px"][det, h]),
            "pck_005": M.pck(raw["joints_px"][det, h], gt["joints_px"][det, h], 0.05),
            "pck_015": M.pck(raw["joints_px"][det, h], gt["joints_px"][det, h], 0.15),
            "gripper_position_error_mm": M.mean_of_finite(M.gripper_position_error_mm(gp["pose"][:, h], gg["pose"][:, h], in_view)),
            "gripper_orientation_error_deg": M.mean_of_finite(M.gripper_orientation_error_deg(gp["pose"][:, h], gg["pose"][:, h], in_view)),
            "approach_axis_error_deg": M.mean_of_finite(M.approach_axis_error_deg(gp["pose"][:, h], gg["pose"][:, h], in_view)),
            "open_close_acc_threshold": M.open_close_accuracy(gp["g_threshold"][:, h], g_true[:, h], in_view),
            "open_close_acc_auto": M.open_close_accuracy(gp["g_auto"][:, h], g_true[:, h], in_view),
            "open_close_acc_manual": (None if np.isnan(g_man.astype(float)).all()
                                      else M.open_close_accuracy(g_man.astype(float), g_true[:, h], in_view)),
            "swap_frames_injected": int(injected.sum()), "swap_frames_repaired": int(repaired.sum()),
            "swap_frames_repaired_correctly": int((repaired & injected).sum()),
            "depth_missing_fraction": float(coverage.hand_missing[h]),
            "depth_missing_frame_fraction": coverage.frame_missing,
        })
    written = write_table("ingest_metrics", pa.Table.from_pylist(out), warehouse, variant)
    return Manifest.from_written("ingest_metrics", written)


@stage_task(name="ingest_keypoint_metrics", version=INGEST_VERSION, key_optional=("variant",))
def ingest_keypoint_metrics(take_dir: Path, task: str | None, warehouse: str, hand_keypoints: Manifest,
                            variant: dict | None = None) -> Manifest | None:
    """The thesis's keypoint metrics (`keypoint_metrics`, dataset `synthetic`: Tables 1, 2, Appendix B)
    of the detections the ingest already made, so a detector that costs seconds per frame (MediaPipe)
    is not run a second time: demoforge.lib.evaluation.keypoints.evaluate_take on the `hand_keypoints` rows, with the
    anchor depth read from the take's depth maps as demoforge.lib.evaluation.keypoints.evaluate_synthetic_take does.
    None for a take without ground truth."""
    take = opened_take(take_dir)
    if not take.has_ground_truth:
        return None
    name = take_task_name(take, task)
    hk = read_table("hand_keypoints", warehouse, variant=variant, task=name, take=take.take_id)
    T, a = arrays(hk, "joints_cam", "joints_px", "present")
    present = a["present"].astype(bool)
    gt, gpx, valid = load_synth_ground_truth(Path(take.path), T)
    cfg = AlignmentConfig()  # measured depth sees the skin: the default surface offset
    uv = np.where(present[..., None, None], a["joints_px"], np.nan)[:, :, np.asarray(cfg.anchors), :]
    anchor_depth = np.full(uv.shape[:-1], np.nan)
    for idx, depth in iter_depth(take, 32):
        anchor_depth[idx], _ = read_depth_robust(depth, uv[idx], cfg.window, cfg.min_valid)
    out = evaluate_take(np.where(present[..., None, None], a["joints_cam"], np.nan), gt, gpx, take.K, present,
                        valid, a["joints_px"], cfg, anchor_depth=anchor_depth, take=take.take_id,
                        obj=str(take.meta.get("task", "")) or None, dataset="synthetic",
                        detector=hk.column("detector")[0].as_py(),
                        detector_version=hk.column("detector_version")[0].as_py(),
                        note="aligned metrics: anchor depth read from the take's depth maps; detections of the ingest")
    schema = get_schema("keypoint_metrics")
    for r in out:
        r.update(dataset="synthetic", take=take.take_id, subject="")
    data = {c.name: [r.get(c.name) for r in out] for c in schema.columns}
    for c in schema.columns:  # NaN-free strings; metrics stay NaN/None (as demoforge.tasks.keypoint_eval writes them)
        if c.type == pa.string():
            data[c.name] = ["" if v is None else str(v) for v in data[c.name]]
    written = write_table("keypoint_metrics", data, warehouse, variant)
    return Manifest.from_written("keypoint_metrics", written)


