#!/usr/bin/env python
"""Build MediaPipe's hand landmarker model file (``hand_landmarker.task``) for the "mediapipe" backend.

mediapipe 1.2.2 (the version the project installs, numpy-2 compatible) ships no model; its Tasks
``HandLandmarker`` loads a ``.task`` file, which is a zip of ``hand_detector.tflite`` (palm
detection) and ``hand_landmarks_detector.tflite`` (21 landmarks + handedness). mediapipe 0.10.21's
wheel carries both models (``mediapipe/modules/palm_detection/palm_detection_full.tflite`` and
``mediapipe/modules/hand_landmark/hand_landmark_full.tflite``). This script downloads that wheel
from PyPI with ``pip download --no-deps`` (nothing is installed), takes the two files out of it and
zips them into the .task file.

Idempotent: does nothing when the target exists and is a valid .task. Default target:
``<sys.prefix>/share/demoforge/hand_landmarker.task`` (the venv running this script), which
lib/perception/detectors/mediapipe_backend.py looks for (or set ``DEMOFORGE_HAND_LANDMARKER``).

    .venv/bin/python scripts/fetch_mediapipe_model.py [--out PATH] [--wheel PATH_TO_0.10.21_WHEEL]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEEL_SPEC = "mediapipe==0.10.21"
MEMBERS = {
    "hand_detector.tflite": "mediapipe/modules/palm_detection/palm_detection_full.tflite",
    "hand_landmarks_detector.tflite": "mediapipe/modules/hand_landmark/hand_landmark_full.tflite",
}


def default_target() -> Path:
    return Path(sys.prefix) / "share" / "demoforge" / "hand_landmarker.task"


def is_valid_task(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            return set(MEMBERS) <= names and all(z.getinfo(n).file_size > 100_000 for n in MEMBERS)
    except (OSError, zipfile.BadZipFile):
        return False


def download_wheel(dest: Path) -> Path:
    """pip download the 0.10.21 wheel for this interpreter (no dependencies, nothing installed)."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:", "-q",
           "-d", str(dest), WHEEL_SPEC]
    subprocess.run(cmd, check=True)
    wheels = sorted(dest.glob("mediapipe-0.10.21-*.whl"))
    if not wheels:
        raise SystemExit(f"pip download {WHEEL_SPEC} produced no wheel in {dest}")
    return wheels[0]


def build_task(wheel: Path, out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with zipfile.ZipFile(wheel) as w, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as z:
        for name, member in MEMBERS.items():
            try:
                data = w.read(member)
            except KeyError as e:
                raise SystemExit(f"{wheel.name} has no {member}; is it mediapipe 0.10.21?") from e
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))  # byte-identical rebuilds
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
    os.replace(tmp, out)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="target .task file")
    ap.add_argument("--wheel", type=Path, default=None, help="use this mediapipe 0.10.21 wheel instead of downloading")
    ap.add_argument("--force", action="store_true", help="rebuild even if the target is valid")
    args = ap.parse_args(argv)
    out = args.out or Path(os.environ.get("DEMOFORGE_HAND_LANDMARKER") or default_target())
    if out.exists() and is_valid_task(out) and not args.force:
        print(f"[fetch_mediapipe_model] ok: {out} exists")
        return 0
    if args.wheel is not None:
        build_task(args.wheel, out)
    else:
        with tempfile.TemporaryDirectory() as d:
            build_task(download_wheel(Path(d)), out)
    if not is_valid_task(out):
        raise SystemExit(f"built {out} but it is not a valid .task")
    sha = hashlib.sha256(out.read_bytes()).hexdigest()[:16]
    print(f"[fetch_mediapipe_model] wrote {out} ({out.stat().st_size / 1e6:.1f} MB, sha256 {sha}...)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
