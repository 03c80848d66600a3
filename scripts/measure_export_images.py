"""Frames per second of `export lerobot --with-images`: physics alone, then physics + rendering +
mp4v encoding at three sizes, over the first N valid episodes of a task.

    .venv/bin/python scripts/measure_export_images.py WAREHOUSE N [TASK]

WAREHOUSE needs the task's episodes and a registered take with camera.json
(scripts/check_exports_sample.py builds one).
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(wh: str, n: int, task: str = "pouring") -> None:
    import cv2

    from demoforge.schemas.reads.episodes import load_episodes, take_cameras
    from demoforge.lib.sim.executor import SimOptions
    from demoforge.lib.sim.render import _resimulate_states, episode_frames

    sel = load_episodes(wh, task, limit=n)
    cams = take_cameras(wh, sorted(set(sel.take.tolist())))
    starts = np.concatenate([[0], np.cumsum(sel.lengths)[:-1]])
    acts = [sel.poses[s:s + L].astype(float) for s, L in zip(starts, sel.lengths)]
    frames = int(sel.lengths.sum())
    t = time.perf_counter()
    for i, a in enumerate(acts):
        _resimulate_states(task, sel.keypoints[i], a, 30.0, SimOptions(stop_on_hard_failure=False))
    phys = time.perf_counter() - t
    print(f"episodes {len(acts)}, frames {frames}; physics only {phys:.1f} s ({frames / phys:.0f} steps/s)")
    for W, H in ((640, 480), (320, 240), (160, 120)):
        w = cv2.VideoWriter(f"/tmp/measure_export_images_{W}.mp4", cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
        t = time.perf_counter()
        for i, a in enumerate(acts):
            cam = cams[sel.take[i]]
            K = np.diag([W / cam.width, H / cam.height, 1.0]) @ cam.K
            for f in episode_frames(task, sel.keypoints[i], a, K, cam.T_world_camera, W, H):
                w.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        w.release()
        tot = time.perf_counter() - t
        print(f"{W}x{H}: physics + render + encode {tot:.1f} s = {frames / tot:.1f} frames/s; "
              f"render + encode alone {tot - phys:.1f} s = {frames / max(tot - phys, 1e-9):.1f} frames/s")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), *sys.argv[3:])
