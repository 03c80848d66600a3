"""Calibration accuracy on the 12 default synthetic takes (the six tasks, original and mirrored, seed 0,
as `demoforge evaluate` generates them), whose camera pose is known exactly.

- table plane: each default take (no board), the plane from the median depth of 8 frames spread over
  the take (depth noise and holes on, as the default takes have): tilt and height error; and with the
  two clicks a person makes on the table's robot-side edge (the true edge's ends, x = -0.3 and +0.3 m at
  y = -0.15 m, projected; the origin is then their midpoint, compared as such): position and rotation.
- board: the same take rendered again with the default A4 ChArUco board (7x5, 38 mm squares) lying at
  the table frame's origin: position and rotation error.

    .venv/bin/python scripts/measure_calibration.py --frames 40 --out docs/results/issue-37-calibration.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from demoforge.lib.calibration import BoardSpec, calibrate, pose_errors
from demoforge.lib.geometry import project_points, transform_inverse, transform_points
from demoforge.lib.synth.take import generate_take
from demoforge.lib.takes import open_take
from demoforge.lib.task_library import TASK_NAMES

EDGE = np.array([[-0.3, -0.15, 0.0], [0.3, -0.15, 0.0]])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=40, help="frames rendered per take")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for task in TASK_NAMES:
            for mirror in (False, True):
                t0 = time.time()
                plain, boarded = Path(d) / f"{task}_{mirror}", Path(d) / f"{task}_{mirror}_board"
                generate_take(task, 0, mirror, plain, max_frames=args.frames, video=False)
                generate_take(task, 0, mirror, boarded, max_frames=args.frames, video=False, board=BoardSpec())
                take = open_take(plain)
                T_true = take.camera.T_world_camera
                plane = pose_errors(calibrate(take, "plane").T_world_camera, T_true)
                uv = project_points(transform_points(transform_inverse(T_true), EDGE), take.K)
                edge_cal = calibrate(take, "plane", edge_clicks=uv)
                shift = np.eye(4)
                shift[:3, 3] = EDGE.mean(axis=0)  # the clicked edge's middle is the estimate's origin
                edge = pose_errors(shift @ edge_cal.T_world_camera, T_true)
                bt = open_take(boarded)
                bc = calibrate(bt, "board")
                board = pose_errors(bc.T_world_camera, T_true)
                row = {"task": task, "mirror": mirror,
                       "plane_tilt_deg": plane["tilt_deg"], "plane_height_mm": plane["height_m"] * 1000,
                       "edge_position_mm": edge["position_m"] * 1000, "edge_rotation_deg": edge["rotation_deg"],
                       "board_position_mm": board["position_m"] * 1000, "board_rotation_deg": board["rotation_deg"],
                       "board_corners": bc.details["corners"], "board_frames": len(bc.details["frames_used"])}
                rows.append(row)
                print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                      f"({time.time() - t0:.0f} s)", flush=True)
    for key in ("plane_tilt_deg", "plane_height_mm", "edge_position_mm", "edge_rotation_deg",
                "board_position_mm", "board_rotation_deg"):
        v = np.array([r[key] for r in rows])
        print(f"{key}: mean {v.mean():.3f}, max {v.max():.3f}")
    if args.out:
        with open(args.out, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    sys.exit(0)


if __name__ == "__main__":
    main()
