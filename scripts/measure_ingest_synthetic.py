"""Measure depth alignment, swap repair, gripper mapping and open/close on synthetic takes.

For each task (seed 0, not mirrored, full take; generated into ``--takes`` if missing) the
SIMULATED detector (demoforge.lib.perception.simulated_detector, detector = "simulated") turns the ground-truth joints
into HaMeR-like predictions; this script then runs demoforge.lib.ingest.alignment, demoforge.lib.ingest.gripper_mapping and
demoforge.lib.evaluation.metrics and prints a Markdown table (and writes JSON with ``--json``).

    .venv/bin/python scripts/measure_ingest_synthetic.py --takes /tmp/ingest_takes [--json out.json]

Numbers are per take, both hands pooled:
* MPJPE raw: detector output vs ground truth, slot by slot (includes the swapped frames);
* MPJPE aligned: after swap repair + depth alignment (+ scale correction), on detected frames;
  PA-MPJPE on the same frames; the thesis variant (anchor joint 2 only, no offset/scale/swap);
* MPJPE final: the output after freeze and fill, on every frame where the hand is in GT;
* gripper errors of the mapped gripper (final joints -> world -> thesis mapping) vs gt_gripper,
  and of the same mapping applied to the GT joints (the mapping's own error);
* open/close accuracy: fixed threshold w, Otsu, automatic (grasp basins), manual ranges;
* swaps: frames detected vs injected;
* speed: align (incl. depth reads) + map + open/close, frames per second.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from demoforge.lib.ingest.alignment import AlignmentConfig, align_to_depth, read_depth_robust  # noqa: E402
from demoforge.lib.geometry import transform_points  # noqa: E402
from demoforge.lib.ingest.gripper_mapping import gripper_state, hand_to_gripper, to_pose8  # noqa: E402
from demoforge.lib.evaluation.metrics import (  # noqa: E402
    approach_axis_error_deg, gripper_orientation_error_deg, gripper_position_error_mm, mpjpe,
    open_close_accuracy, pa_mpjpe,
)
from demoforge.lib.perception.simulated_detector import simulate_detections  # noqa: E402

TASKS = ("pouring", "trash_in_bin", "paper_in_case", "mix_bowl", "open_container", "empty_vase")


from demoforge.schemas.core import column_numpy as _col  # noqa: E402


def load_take(d: Path) -> dict:
    import pyarrow.parquet as pq

    cam = json.loads((d / "camera.json").read_text())
    ann = json.loads((d / "annotations.json").read_text())
    hj = pq.read_table(d / "ground_truth" / "gt_hand_joints.parquet")
    gg = pq.read_table(d / "ground_truth" / "gt_gripper.parquet")
    n = len(hj) // 2
    out = {
        "K": np.asarray(cam["K"], float), "T_wc": np.asarray(cam["T_world_camera"], float),
        "annotations": ann,
        "joints_world": _col(hj, "joints_world").reshape(n, 2, 21, 3),
        "joints_cam": _col(hj, "joints_camera").reshape(n, 2, 21, 3),
        "joints_px": _col(hj, "joints_px").reshape(n, 2, 21, 2),
        "visible": _col(hj, "visible").reshape(n, 2, 21),
        "present": _col(hj, "present").reshape(n, 2),
        "pose8": _col(gg, "pose").reshape(n, 2, 8),
        "closed": _col(gg, "closed").reshape(n, 2),
        "aperture": _col(gg, "aperture").reshape(n, 2),
    }
    files = sorted((d / "depth").glob("*.npy"))
    out["depth"] = np.stack([np.load(f) for f in files])
    return out


def ensure_take(task: str, root: Path, seed: int = 0, mirror: bool = False) -> Path:
    d = root / f"{task}_s{seed}_m{int(mirror)}"
    if not (d / "take.json").exists():
        from demoforge.lib.synth.take import generate_take

        t0 = time.time()
        generate_take(task, seed, mirror, d, video=False)
        print(f"generated {d} in {time.time() - t0:.0f} s", file=sys.stderr)
    return d


def surface_offset(take: dict, anchors=(0, 1, 2, 5, 9, 13, 17)) -> float:
    """Median (joint z - robust depth at the joint's exact pixel) over visible anchors."""
    a = list(anchors)
    z, _ = read_depth_robust(take["depth"], take["joints_px"][:, :, a], window=5, min_valid=3)
    dz = take["joints_cam"][:, :, a, 2] - z
    vis = take["visible"][:, :, a] & np.isfinite(dz)
    return float(np.median(dz[vis]))


def measure(task: str, take: dict, det_seed: int = 0, w_gripper: float = 0.06,
            config: AlignmentConfig | None = None) -> dict:
    K, T_wc = take["K"], take["T_wc"]
    gt_cam, gt_world = take["joints_cam"], take["joints_world"]
    T = gt_cam.shape[0]
    det = simulate_detections(gt_cam, K, seed=det_seed)
    gt_present = take["present"]

    cfg = config or AlignmentConfig()
    t0 = time.perf_counter()
    res = align_to_depth(det.joints_cam, take["depth"], K, joints_px=det.joints_px, config=cfg)
    t1 = time.perf_counter()
    thesis = align_to_depth(det.joints_cam, take["depth"], K, joints_px=None, config=AlignmentConfig.thesis())

    m_det = res.detected & gt_present
    row = {"task": task, "frames": T, "detector": det.detector}
    row["mpjpe_raw_m"] = mpjpe(det.joints_cam, gt_cam, det.present[..., None] & gt_present[..., None])
    row["mpjpe_aligned_mm"] = 1e3 * mpjpe(res.joints_aligned, gt_cam, m_det[..., None])
    row["pa_mpjpe_mm"] = 1e3 * pa_mpjpe(res.joints_aligned, gt_cam, m_det[..., None])
    row["mpjpe_thesis_mm"] = 1e3 * mpjpe(thesis.joints_aligned, gt_cam, (thesis.detected & gt_present)[..., None])
    no_scale = align_to_depth(det.joints_cam, take["depth"], K, joints_px=det.joints_px,
                              config=cfg.with_(scale_correction="none"))
    row["mpjpe_noscale_mm"] = 1e3 * mpjpe(no_scale.joints_aligned, gt_cam, m_det[..., None])
    row["mpjpe_final_mm"] = 1e3 * mpjpe(res.joints_cam, gt_cam, gt_present[..., None])
    row["mpjpe_final_thesis_mm"] = 1e3 * mpjpe(thesis.joints_cam, gt_cam, gt_present[..., None])
    row["no_depth_frames"] = int(res.no_depth.sum())
    row["frozen_frames"] = int(res.outlier_frozen.sum())
    row["filled_frames"] = int(res.filled_missing.sum())
    inj = det.injected_swap
    got = res.swap_frames
    row["swaps_injected"] = int(inj.sum())
    row["swaps_repaired"] = int((got & inj).sum())
    row["swaps_false"] = int((got & ~inj).sum())

    # gripper mapping
    t2 = time.perf_counter()
    jw = transform_points(T_wc, res.joints_cam)
    pose7, d = hand_to_gripper(jw)
    g_auto = gripper_state(d, "auto")
    t3 = time.perf_counter()
    gt8 = take["pose8"]
    mask = gt_present
    row["grip_pos_mm"] = float(np.nanmean(gripper_position_error_mm(pose7, gt8, mask)))
    row["grip_rot_deg"] = float(np.nanmean(gripper_orientation_error_deg(pose7, gt8, mask)))
    row["grip_rot_deg_median"] = float(np.nanmedian(gripper_orientation_error_deg(pose7, gt8, mask)))
    row["grip_approach_deg"] = float(np.nanmean(approach_axis_error_deg(pose7, gt8, mask)))
    p_gt, _ = hand_to_gripper(gt_world)
    row["map_gt_pos_mm"] = float(np.nanmean(gripper_position_error_mm(p_gt, gt8, mask)))
    row["map_gt_rot_deg"] = float(np.nanmean(gripper_orientation_error_deg(p_gt, gt8, mask)))
    jw_t = transform_points(T_wc, thesis.joints_cam)
    p_th, d_th = hand_to_gripper(jw_t)
    row["grip_pos_thesis_mm"] = float(np.nanmean(gripper_position_error_mm(p_th, gt8, mask)))
    row["grip_rot_thesis_deg"] = float(np.nanmean(gripper_orientation_error_deg(p_th, gt8, mask)))

    g_true = np.where(take["closed"], 0.0, 1.0)
    row["acc_threshold"] = open_close_accuracy(gripper_state(d, "threshold", w_gripper=w_gripper), g_true, mask)
    row["acc_otsu"] = open_close_accuracy(gripper_state(d, "otsu"), g_true, mask)
    row["acc_auto"] = open_close_accuracy(g_auto, g_true, mask)
    row["acc_auto_per_hand"] = [open_close_accuracy(g_auto[:, h], g_true[:, h], mask[:, h]) for h in range(2)]
    ranges = take["annotations"]["gripper_closed_ranges"]
    row["acc_manual"] = open_close_accuracy(gripper_state(d, "manual", closed_ranges=ranges), g_true, mask)
    row["acc_auto_gt_joints"] = open_close_accuracy(gripper_state(take["aperture"], "auto"), g_true, mask)
    row["align_s"] = t1 - t0
    row["map_s"] = t3 - t2
    row["fps_align_map"] = T / ((t1 - t0) + (t3 - t2))
    pose8 = to_pose8(pose7, g_auto)
    row["pose8_finite"] = bool(np.isfinite(pose8[gt_present]).all())
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--takes", type=Path, default=Path("/tmp/ingest_takes"))
    ap.add_argument("--tasks", nargs="*", default=list(TASKS))
    ap.add_argument("--seed", type=int, default=0, help="take seed")
    ap.add_argument("--det-seeds", type=int, nargs="*", default=[0], help="simulated detector seeds")
    ap.add_argument("--w-gripper", type=float, default=0.06)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    offsets = []
    for task in args.tasks:
        take = load_take(ensure_take(task, args.takes, args.seed))
        offsets.append(surface_offset(take))
        for ds in args.det_seeds:
            r = measure(task, take, det_seed=ds, w_gripper=args.w_gripper)
            r["det_seed"] = ds
            r["surface_offset_mm"] = 1e3 * offsets[-1]
            rows.append(r)
            print(json.dumps(r), file=sys.stderr)
    cols = [("task", "task"), ("det_seed", "det"), ("frames", "T"),
            ("mpjpe_raw_m", "MPJPE raw (m)"), ("mpjpe_thesis_mm", "MPJPE thesis-aligned (mm)"),
            ("mpjpe_noscale_mm", "MPJPE aligned, no scale (mm)"), ("mpjpe_aligned_mm", "MPJPE aligned (mm)"),
            ("pa_mpjpe_mm", "PA-MPJPE (mm)"), ("mpjpe_final_mm", "MPJPE final (mm)"),
            ("grip_pos_mm", "grip pos (mm)"), ("grip_rot_deg", "grip rot (deg)"),
            ("grip_approach_deg", "approach (deg)"), ("map_gt_pos_mm", "GT-map pos (mm)"),
            ("map_gt_rot_deg", "GT-map rot (deg)"), ("acc_threshold", f"acc w={args.w_gripper}"),
            ("acc_otsu", "acc Otsu"), ("acc_auto", "acc auto"), ("acc_manual", "acc manual"),
            ("swaps_injected", "swaps inj"), ("swaps_repaired", "swaps fixed"), ("swaps_false", "swaps false"),
            ("fps_align_map", "frames/s")]
    print("| " + " | ".join(c[1] for c in cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        cells = []
        for k, _ in cols:
            v = r[k]
            cells.append(f"{v:.3f}" if isinstance(v, float) and k.startswith(("acc", "mpjpe_raw")) else
                         f"{v:.1f}" if isinstance(v, float) else str(v))
        print("| " + " | ".join(cells) + " |")
    print(f"\nsurface offset (joint z - depth at its pixel, visible anchors), mm: "
          f"{', '.join(f'{1e3 * o:.1f}' for o in offsets)}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
