"""Each recording format against the take folder it was made from: a synthetic trash_in_bin take
(seed 0, the first N frames) written as a RealSense recording (the SDK's recorder; a .bag in the SDK's
ROS 1 layout written with rosbags), ROS 2 bags (rosbags:
MCAP with 16UC1 depth, SQLite with 32FC1), Record3D (.r3d, depth at the RGB's size and at a quarter of
it), each ingested with the simulated detector like the folder; prints the largest gripper position
difference (mm) and rotation difference (deg) over the frames where both have a pose, and how long
opening (indexing) and ingesting took.

    .venv/bin/python scripts/measure_take_sources.py --frames 60
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from demoforge.flows.ingest import ingest_take
from demoforge.lib.synth.take import generate_take
from demoforge.lib.takes import open_take
from demoforge.lib.takes.sources.writers import write_realsense, write_realsense_bag, write_record3d, write_rosbag2


def poses(wh: Path) -> np.ndarray:
    t = pq.read_table(next((wh / "gripper_poses").rglob("*.parquet"))).to_pydict()
    order = np.lexsort((np.array(t["hand"]), np.array(t["frame"])))
    return np.array(t["pose"], float)[order]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        take = d / "trash"
        generate_take("trash_in_bin", 0, False, take, max_frames=args.frames, video=False)
        ingest_take(str(take), str(d / "wh_folder"), show_progress=False)
        ref = poses(d / "wh_folder")
        writers = {
            "realsense .db3 (SDK recorder, z16 0.1 mm)": lambda p: write_realsense(take, p.with_suffix(".db3")),
            "realsense .bag (the SDK's ROS 1 layout, rosbags; mono16 0.1 mm)": lambda p: write_realsense_bag(take, p.with_suffix(".bag")),
            "ROS 2 MCAP (16UC1 mm)": lambda p: write_rosbag2(take, p, storage="mcap", depth_encoding="16UC1"),
            "ROS 2 SQLite .db3 (32FC1 m)": lambda p: write_rosbag2(take, p, storage="sqlite3", depth_encoding="32FC1"),
            "Record3D .r3d (depth at 640x480)": lambda p: write_record3d(take, p.with_suffix(".r3d")),
            "Record3D .r3d (depth at 160x120)": lambda p: write_record3d(take, p.with_suffix(".r3d"), depth_size=(160, 120)),
        }
        for k, (name, write) in enumerate(writers.items()):
            rec = write(d / f"rec{k}")
            t0 = time.time()
            opened = open_take(rec)
            t1 = time.time()
            ingest_take(str(rec), str(d / f"wh{k}"), show_progress=False)
            t2 = time.time()
            got = poses(d / f"wh{k}")
            ok = ~np.isnan(ref).any(1) & ~np.isnan(got).any(1)
            dpos = np.abs(got[ok, :3] - ref[ok, :3]).max() * 1000
            dot = np.clip(np.abs((got[ok, 3:7] * ref[ok, 3:7]).sum(1)), 0, 1)
            drot = np.degrees(2 * np.arccos(dot)).max()
            same_nan = np.array_equal(np.isnan(got), np.isnan(ref))
            print(f"{name}: {opened.n_frames} frames ({opened.status_counts()}), poses on {ok.sum()} frame-hands "
                  f"(same missing ones: {same_nan}), max position diff {dpos:.3f} mm, max rotation diff {drot:.3f} deg, "
                  f"gripper state equal: {np.array_equal(got[ok, 7], ref[ok, 7])}; index {t1 - t0:.1f} s, ingest {t2 - t1:.1f} s",
                  flush=True)


if __name__ == "__main__":
    main()
