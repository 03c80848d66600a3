"""Issue 19: would zooming in let MediaPipe find the synthetic hands? An upper bound, with an oracle.

For every STEP-th frame of a synthetic take, MediaPipe (image mode) runs once on the full 640x480 frame
and once per ground-truth hand on a square crop around that hand (MARGIN x its 2D box, resized to SIZE
px; the crop is placed where the hand really is, which no real detector knows: an upper bound for any
region-of-interest or tiling scheme). Both are scored with the detection metrics of
`demoforge evaluate-detection` (demoforge.lib.evaluation.detection.score_take, subset `all`).

    .venv/bin/python scripts/measure_detection_zoom.py TAKE_DIR [STEP] [MARGIN] [SIZE]

Results: docs/results/issue-19-detection.md ("Zooming in, an upper bound").
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

from demoforge.lib.evaluation.detection import load_ground_truth, score_take
from demoforge.lib.perception.detectors import HandCandidate
from demoforge.lib.perception.detectors.mediapipe_backend import MediaPipeDetector
from demoforge.lib.takes import open_take
from demoforge.lib.takes.reader import iter_frames


def main(take_dir: Path, step: int = 3, margin: float = 2.5, size: int = 256) -> None:
    take, gt = open_take(take_dir), load_ground_truth(take_dir)
    frames = list(range(0, take.n_frames, step))
    full: list[list] = [[] for _ in range(take.n_frames)]
    crop: list[list] = [[] for _ in range(take.n_frames)]
    seconds = {"full": 0.0, "crop": 0.0}
    with MediaPipeDetector(running_mode="image") as two, MediaPipeDetector(running_mode="image", num_hands=1) as one:
        for batch in iter_frames(take, batch_size=16, frames=frames):
            for rgb, i in zip(batch.rgb, batch.indices.tolist()):
                t0 = time.perf_counter()
                full[i] = two.detect_image(rgb, take.camera.K)
                seconds["full"] += time.perf_counter() - t0
                for h in range(2):
                    px = gt["px"][i, h]
                    if not np.isfinite(px).any():
                        continue
                    lo, hi = np.nanmin(px, 0), np.nanmax(px, 0)
                    side = float(max(hi - lo)) * margin
                    x0, y0 = (lo + hi) / 2 - side / 2
                    s = size / side
                    t0 = time.perf_counter()
                    sub = cv2.warpAffine(rgb, np.array([[s, 0, -x0 * s], [0, s, -y0 * s]]), (size, size))
                    for c in one.detect_image(sub):
                        crop[i].append(HandCandidate(handedness=c.handedness, confidence=c.confidence,
                                                     joints_px=c.joints_px / s + np.array([x0, y0]),
                                                     joints_cam=c.joints_cam))
                    seconds["crop"] += time.perf_counter() - t0
    chosen = np.zeros(len(gt["in_view"]), bool)
    chosen[frames] = True
    gt = {**gt, "in_view": gt["in_view"] & chosen[:, None, None]}     # score the chosen frames only
    for name, cands in (("full frame", full), (f"oracle crop x{margin}, {size} px", crop)):
        r = score_take(cands, gt)[0]
        print(f"| {take_dir.name} | {name} | {r['hand_frames']} | {r['detection_rate']:.3f} | "
              f"{r['handedness_acc']:.3f} | {r['mpjpe_2d_px']:.1f} | {r['pck15']:.3f} | "
              f"{1000 * seconds['full' if name == 'full frame' else 'crop'] / len(frames):.0f} |")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(Path(a[0]), *(int(a[1]),) if len(a) > 1 else (), *(float(a[2]),) if len(a) > 2 else (),
         *(int(a[3]),) if len(a) > 3 else ())
