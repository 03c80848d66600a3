"""Issue 19 point 5: the default synthetic takes ingested with the simulated detector and with MediaPipe,
side by side, per task: detection rate, gripper position / rotation error, open/close accuracy, the robot
executing the ingested demonstration, and what explains MediaPipe's figures (handedness, 2D error, depth).

    PYTHONPATH=. MUJOCO_GL=egl .venv/bin/python scripts/measure_real_detector.py [WAREHOUSE] [--hand-style skin]

Prints Markdown tables (docs/results/issue-19-real-detector.md) and the extra wall time of the MediaPipe
ingest per take (what `make evaluate` pays for the second detector).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def handedness_rows(wh: str) -> list[dict]:
    """Per take and hand label of MediaPipe's detections: how many sit on the hand of that label and how
    many on the other hand (2D distance to each ground-truth hand), and the 2D error to the nearer one."""
    from demoforge.lib.takes import open_take
    from demoforge.schemas.catalog import query
    from demoforge.schemas.core import read_table, read_table_file
    from demoforge.schemas.reads.per_hand import arrays

    out = []
    for r in query("SELECT path FROM takes ORDER BY take", wh).to_pylist():
        take = open_take(r["path"])
        hk = read_table("hand_keypoints", wh, variant={"detector": "mediapipe"}, take=take.take_id)
        if hk.num_rows == 0:
            continue
        _, d = arrays(hk, "joints_px", "present")
        _, gt = arrays(read_table_file("gt_hand_joints", take.ground_truth_dir / "gt_hand_joints.parquet"),
                       "joints_px", "present")
        for h, hand in enumerate(("left", "right")):
            det = d["present"][:, h].astype(bool)
            own = np.linalg.norm(d["joints_px"][:, h] - gt["joints_px"][:, h], axis=-1).mean(-1)
            oth = np.linalg.norm(d["joints_px"][:, h] - gt["joints_px"][:, 1 - h], axis=-1).mean(-1)
            own = np.where(gt["present"][:, h], own, np.inf)
            oth = np.where(gt["present"][:, 1 - h], oth, np.inf)
            n = int(det.sum())
            on_other = det & (oth < own)
            near = np.minimum(own, oth)[det]
            out.append({"task": str(take.meta.get("task")), "take": take.take_id, "hand": hand,
                        "in_view": int(gt["present"][:, h].sum()), "detections": n,
                        "on_other_hand": int(on_other.sum()),
                        "median_2d_px_nearest": float(np.median(near[np.isfinite(near)])) if np.isfinite(near).any() else float("nan")})
    return out


def error_breakdown(wh: str) -> list[dict]:
    """MediaPipe's gripper position error split by what the ingest had in each frame: a detection on the
    hand of its own label, one on the other hand (left/right confusion the tracker did not repair), or
    no detection (filled / held). For frames on the own hand, the error split into the camera's depth
    axis and the image plane: is it the 2D keypoints or the depth?"""
    from demoforge.lib.ingest.alignment import project
    from demoforge.lib.takes import open_take
    from demoforge.schemas.catalog import query
    from demoforge.schemas.core import read_table, read_table_file
    from demoforge.schemas.reads.per_hand import arrays

    cats: dict[str, dict[str, list]] = {}
    for r in query("SELECT path FROM takes ORDER BY take", wh).to_pylist():
        take = open_take(r["path"])
        v = {"detector": "mediapipe"}
        al = read_table("aligned_keypoints", wh, variant=v, take=take.take_id)
        if al.num_rows == 0:
            continue
        _, a = arrays(al, "joints_cam", "detected", "present")
        _, gp = arrays(read_table("gripper_poses", wh, variant=v, take=take.take_id), "pose")
        gd = take.ground_truth_dir
        _, gt = arrays(read_table_file("gt_hand_joints", gd / "gt_hand_joints.parquet"), "joints_px", "present")
        _, gg = arrays(read_table_file("gt_gripper", gd / "gt_gripper.parquet"), "pose")
        Twc = np.asarray(take.camera.T_world_camera, float)
        Tcw = np.linalg.inv(Twc)
        px = project(a["joints_cam"], take.K)
        for h in (0, 1):
            own = np.linalg.norm(px[:, h] - gt["joints_px"][:, h], axis=-1).mean(-1)
            oth = np.linalg.norm(px[:, h] - gt["joints_px"][:, 1 - h], axis=-1).mean(-1)
            oth = np.where(gt["present"][:, 1 - h], oth, np.inf)
            view = gt["present"][:, h].astype(bool)
            det = a["detected"][:, h].astype(bool) & view
            on_own = det & ~(oth < own)
            kinds = {"detected, on its own hand": on_own, "detected, on the other hand": det & ~on_own,
                     "not detected (filled or held)": view & ~det & a["present"][:, h].astype(bool),
                     "no pose (hand absent)": view & ~a["present"][:, h].astype(bool)}
            d_world = gp["pose"][:, h, :3] - gg["pose"][:, h, :3]
            d_cam = d_world @ Tcw[:3, :3].T
            for k, m in kinds.items():
                c = cats.setdefault(k, {"frames": [], "err": [], "depth": [], "plane": [], "px": []})
                c["frames"].append(int(m.sum()))
                ok = m & np.isfinite(d_world).all(-1)
                c["err"].append(1000 * np.linalg.norm(d_world[ok], axis=-1))
                c["depth"].append(1000 * np.abs(d_cam[ok, 2]))
                c["plane"].append(1000 * np.linalg.norm(d_cam[ok, :2], axis=-1))
                c["px"].append(own[ok])
    out = []
    total = sum(sum(c["frames"]) for c in cats.values())
    for k, c in cats.items():
        med = {n: (float(np.median(np.concatenate(c[n]))) if np.concatenate(c[n]).size else float("nan"))
               for n in ("err", "depth", "plane", "px")}
        out.append({"frames (hand in view)": k, "share": round(sum(c["frames"]) / max(total, 1), 3),
                    "median gripper error (mm)": round(med["err"], 1),
                    "of it along the camera axis (mm)": round(med["depth"], 1),
                    "in the image plane (mm)": round(med["plane"], 1),
                    "median 2D joint error to its own hand (px)": round(med["px"], 1)})
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("warehouse", nargs="?", default="/tmp/demoforge-issue19-real-detector")
    ap.add_argument("--hand-style", default="capsule", help="capsule (the default takes) or skin")
    ap.add_argument("--task", action="append", help="only these tasks (default: all six)")
    args = ap.parse_args()

    from demoforge.flows.ingest import ingest_side_by_side, ingest_take
    from demoforge.flows.synth import synthesize_takes
    from demoforge.lib.evaluation.markdown import markdown_table
    from demoforge.lib.task_library import TASK_NAMES
    from demoforge.schemas.catalog import query

    wh = str(Path(args.warehouse).resolve())
    t0 = time.perf_counter()
    manifests = synthesize_takes(wh, tasks=args.task or list(TASK_NAMES), takes=1, seed=0, mirror="both",
                                 video=False, show_progress=False, hand_style=args.hand_style)
    print(f"synthesized {len(manifests)} takes in {time.perf_counter() - t0:.0f} s")
    cost = []
    for m in manifests:
        t = time.perf_counter()
        ingest_take(m.path, wh, show_progress=False)
        t_sim = time.perf_counter() - t
        t = time.perf_counter()
        res = ingest_side_by_side(m.path, wh, detectors=["simulated", "mediapipe"])
        t_both = time.perf_counter() - t
        cost.append((Path(m.path).name, t_sim, t_both))
        errors = {d: r["error"] for d, r in res.items() if r["error"]}
        print(f"{Path(m.path).name}: simulated ingest {t_sim:.1f} s; side by side (MediaPipe ingest, its keypoint "
              f"metrics, both robot checks) {t_both:.1f} s {errors or ''}", flush=True)

    print("\n### Per task and detector (default takes: plain and mirrored)\n")
    t = query("""
        SELECT m.task, m.detector, round(avg(m.detected_fraction), 3) AS detection_rate,
               count(*) FILTER (WHERE isnan(m.gripper_position_error_mm)) || '/' || count(*) AS hands_without_pose,
               round(avg(m.gripper_position_error_mm) FILTER (WHERE NOT isnan(m.gripper_position_error_mm)), 1) AS gripper_pos_mm,
               round(avg(m.gripper_orientation_error_deg) FILTER (WHERE NOT isnan(m.gripper_orientation_error_deg)), 1) AS gripper_rot_deg,
               round(avg(m.open_close_acc_auto), 3) AS open_close_auto,
               round(avg(m.mpjpe_2d_px) FILTER (WHERE NOT isnan(m.mpjpe_2d_px)), 1) AS mpjpe_2d_px,
               round(avg(m.pck_015) FILTER (WHERE NOT isnan(m.pck_015)), 3) AS pck_015,
               round(1000 * avg(m.mpjpe_aligned_m) FILTER (WHERE NOT isnan(m.mpjpe_aligned_m)), 0) AS mpjpe_aligned_mm,
               any_value(d.successes) || '/' || any_value(d.takes) AS robot_success
        FROM ingest_metrics m JOIN (SELECT task, detector, count(*) FILTER (WHERE success) AS successes, count(*) AS takes
                                     FROM ingested_demo_checks GROUP BY ALL) d USING (task, detector)
        GROUP BY m.task, m.detector ORDER BY m.task, m.detector DESC""", wh)
    print(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
    t = query("""
        SELECT detector, count(*) AS takes, count(*) FILTER (WHERE success) AS successes,
               round(avg(CASE WHEN success THEN 1.0 ELSE 0.0 END), 3) AS success_rate,
               string_agg(DISTINCT CASE WHEN success THEN NULL ELSE failure END, ', ') AS failures,
               round(avg(valid_left), 3) AS valid_left, round(avg(valid_right), 3) AS valid_right,
               sum(trusted_hands) AS trusted_hands
        FROM ingested_demo_checks GROUP BY detector ORDER BY detector DESC""", wh)
    print("\n### The robot executing the ingested demonstrations\n")
    print(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
    t = query("""SELECT take, detector, status, success, failure, left(detail, 90) AS detail,
                        round(valid_left, 2) AS valid_left, round(valid_right, 2) AS valid_right, trusted_hands
                 FROM ingested_demo_checks ORDER BY take, detector DESC""", wh)
    print("\n### Per take\n")
    print(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
    hr = handedness_rows(wh)
    print("\n### MediaPipe's detections: on which hand (2D distance to each ground-truth hand)\n")
    print(markdown_table(list(hr[0]), [[round(v, 1) if isinstance(v, float) else v for v in r.values()] for r in hr]))
    tot = sum(r["detections"] for r in hr)
    other = sum(r["on_other_hand"] for r in hr)
    print(f"\nall takes: {other}/{tot} MediaPipe detections ({100 * other / max(tot, 1):.0f} %) lie on the other hand")
    eb = error_breakdown(wh)
    print("\n### MediaPipe's gripper position error by what the ingest had in the frame (all takes)\n")
    print(markdown_table(list(eb[0]), [list(r.values()) for r in eb]))
    t = query("""SELECT detector, hand, sum(frames_detected) AS detected, sum(frames_accepted) AS accepted,
                        sum(frames_isolated) AS isolated, sum(frames_depth_inconsistent) AS depth_inconsistent,
                        sum(frames_duplicate) AS duplicate, sum(frames_filled) AS filled,
                        sum(frames_tracked) AS tracked, sum(frames) AS frames,
                        count(*) FILTER (WHERE trusted) AS trusted_takes, count(*) AS takes
                 FROM hand_presence GROUP BY detector, hand ORDER BY detector DESC, hand""", wh)
    print("\n### The hand tracker on each detector's detections (all takes)\n")
    print(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
    extra = [b for _, _, b in cost]
    print(f"\nside-by-side cost per take (simulated ingest cached): mean {np.mean(extra):.1f} s, "
          f"min {np.min(extra):.1f} s, max {np.max(extra):.1f} s, total {np.sum(extra):.0f} s over {len(extra)} takes")


if __name__ == "__main__":
    main()
