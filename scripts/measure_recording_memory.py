"""Peak memory of reading a long recording: a 2-minute 848 x 480 RealSense recording at 30 fps (3,600
frames, written by the SDK's recorder from a synthetic take's frames, resized and looped) is indexed
(the first `open_take`), then every frame is decoded (`iter_frames`, what ingest's frame check does),
in a fresh process each, beside the same for a 10-second one: bounded memory means the peak does not
grow with the length. Also how long each takes.

    .venv/bin/python scripts/measure_recording_memory.py write --seconds 120 --out /tmp/rs_120s.db3
    .venv/bin/python scripts/measure_recording_memory.py read /tmp/rs_120s.db3
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

W, H, FPS = 848, 480, 30.0


def write(seconds: float, out: Path) -> None:
    import cv2

    from demoforge.lib.synth.take import generate_take
    from demoforge.lib.takes import iter_frames, open_take
    from demoforge.lib.takes.sources.recording import scale_intrinsics
    from demoforge.lib.takes.sources.writers import write_realsense
    from demoforge.lib.takes.types import CameraInfo

    with tempfile.TemporaryDirectory() as d:
        generate_take("pouring", 0, False, Path(d) / "t", max_frames=30, video=False)
        take = open_take(Path(d) / "t")
        base = [(cv2.resize(r, (W, H), interpolation=cv2.INTER_AREA), cv2.resize(z, (W, H), interpolation=cv2.INTER_NEAREST))
                for b in iter_frames(take) for r, z in zip(b.rgb, b.depth)]
        K = scale_intrinsics(take.K, (take.camera.width, take.camera.height), (W, H))
    cam = CameraInfo(K=K, width=W, height=H, T_world_camera=None, fps=FPS)
    n = int(round(seconds * FPS))
    frames = ((i, *base[i % len(base)]) for i in range(n))
    t0 = time.time()
    write_realsense(None, out, frames=frames, camera=cam, depth_units=0.001, pace_s=1 / FPS)
    print(f"wrote {out}: {n} frames of {W} x {H}, {out.stat().st_size / 1e9:.2f} GB in {time.time() - t0:.0f} s")


def read(path: Path) -> None:
    from demoforge.lib.takes import iter_frames, open_take

    def peak_mb() -> float:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    t0 = time.time()
    take = open_take(path, require_pose=False)
    t1 = time.time()
    print(f"index: {take.n_frames} frames in {t1 - t0:.1f} s, peak RSS {peak_mb():.0f} MB")
    n, checksum = 0, 0.0
    for b in iter_frames(take, batch_size=32):
        n += len(b.indices)
        checksum += float(b.depth[:, ::97, ::97].sum())
    print(f"decode: {n} frames in {time.time() - t1:.1f} s ({n / (time.time() - t1):.1f} frames/s), "
          f"peak RSS {peak_mb():.0f} MB (checksum {checksum:.1f})")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("write")
    w.add_argument("--seconds", type=float, default=120.0)
    w.add_argument("--out", type=Path, required=True)
    r = sub.add_parser("read")
    r.add_argument("path", type=Path)
    a = ap.parse_args()
    write(a.seconds, a.out) if a.cmd == "write" else read(a.path)
