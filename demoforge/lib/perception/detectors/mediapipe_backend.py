"""The "mediapipe" backend: Google MediaPipe's hand landmarker, a real detector that runs offline on CPU.

Dependency (see requirements/mediapipe.txt): ``mediapipe==1.2.2`` installed with ``--no-deps`` plus
``absl-py`` and ``flatbuffers`` (it works with numpy 2; its declared opencv-contrib-python would
replace the project's headless OpenCV, and sounddevice is only for audio). 1.2.2 ships no model:
``scripts/fetch_mediapipe_model.py`` builds ``hand_landmarker.task`` from the palm-detection and
hand-landmark models of the mediapipe 0.10.21 wheel.

Model file lookup: the ``model_path`` argument, else ``$DEMOFORGE_HAND_LANDMARKER``, else
``<sys.prefix>/share/demoforge/hand_landmarker.task``.

Output per detected hand (:class:`HandCandidate`):

* ``joints_px``: the 21 landmarks' normalised image coordinates times (width, height).
* ``joints_cam``: MediaPipe's metric "world" landmarks (metres, origin near the hand's centre,
  camera-aligned axes) placed in the camera frame by the translation whose projection best fits
  the 2D landmarks (:func:`demoforge.lib.perception.detectors.fit_translation_to_2d`, linear least squares). The
  absolute depth therefore comes from the assumed hand size, like HaMeR's: depth-align it
  downstream (thesis 3.1.2).
* ``confidence``: the handedness score (MediaPipe's hand presence score is applied as a threshold
  inside the landmarker, ``min_hand_presence_confidence``, and not returned by the Tasks API).
* ``handedness``: MediaPipe's label mapped to the person's hand. Measured on the labelled real
  photos (tests/lib/perception/detectors/test_mediapipe_backend_real_photos.py; COCO-WholeBody and CMU
  Panoptic, ordinary non-mirrored photos): the Tasks API's "Left"/"Right" category names of the 0.10.21 models name
  the person's hand correctly for non-mirrored images, so ``mirrored=False`` (default) keeps them;
  pass ``mirrored=True`` for selfie-mirrored video. The raw label is kept in ``extra``.

Image order: RGB (what demoforge.lib.ingest gives). Running modes: ``"image"`` treats every frame
independently, like HaMeR in the thesis; ``"video"`` runs the palm detector only when it has lost
a hand and otherwise tracks the landmarks from the previous frame (frame indices must increase;
timestamps = frame index / fps). ``"auto"`` (default) uses video mode for takes
(:meth:`MediaPipeDetector.detect_take`, or between :meth:`start_take` and :meth:`end_take`; a fresh
tracker per take) and image mode for single images (:meth:`detect_image` outside a take, e.g. the
labelled photos). On the default synthetic takes video mode finds far more hands than image mode
(docs/results/issue-19-detection.md).
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
import weakref
from pathlib import Path
from typing import Sequence

import numpy as np

from demoforge.lib.perception.detectors import (
    N_JOINTS, DetectorError, HandCandidate, HandDetector, fit_translation_to_2d,
)
from demoforge.lib.settings import read_settings

__all__ = ["MediaPipeDetector", "default_model_path", "LABEL_IS_PERSON_HAND", "native_stderr"]

MODEL_ENV = "DEMOFORGE_HAND_LANDMARKER"
#: Whether MediaPipe Tasks' category name equals the person's hand on a NON-mirrored image
#: (measured on the labelled photos, see the module docstring).
LABEL_IS_PERSON_HAND = True


#: Set to 1 to let MediaPipe's C++ warnings through to the terminal (they are kept out by default).
SHOW_NATIVE_LOGS_ENV = "DEMOFORGE_NATIVE_LOGS"  # read by demoforge.lib.settings
#: What MediaPipe's C++ side (glog, TFLite) writes on every graph it builds or first runs: warnings about
#: the model file and the graph, none of them about the user's data.
_NATIVE_NOISE = re.compile(rb"^(?:[WI]0000 |INFO: Created TensorFlow Lite|WARNING: Logging before InitGoogle|"
                           rb"WARNING: Read-only tensor)")


class NativeStderr:
    """File descriptor 2 diverted to a scratch file around each call into MediaPipe's C++ code, which
    writes to it directly (Python's ``sys.stderr`` and logging cannot filter it, and glog's and TF's
    environment variables do not silence it): the known warnings are kept in :attr:`messages`, any
    other byte (an error, or another thread's output) is written through to the real stderr."""

    MAX_MESSAGES = 200

    def __init__(self):
        self.messages: list[str] = []
        self._lock = threading.Lock()  # fd 2 belongs to the whole process
        self._scratch = None

    @contextlib.contextmanager
    def diverted(self):
        if read_settings().native_logs:
            yield
            return
        with self._lock:
            try:
                sys.stderr.flush()
                saved = os.dup(2)
            except (OSError, ValueError, AttributeError):  # no usable stderr: nothing to keep clean
                yield
                return
            if self._scratch is None:
                self._scratch = tempfile.TemporaryFile()
            os.dup2(self._scratch.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                self._sort()

    def _sort(self) -> None:
        f = self._scratch
        f.seek(0)
        data = f.read()
        f.seek(0)
        f.truncate()
        keep = []
        for line in data.splitlines(keepends=True):
            if _NATIVE_NOISE.match(line):
                if len(self.messages) < self.MAX_MESSAGES:
                    self.messages.append(line.decode("utf-8", "replace").rstrip())
            else:
                keep.append(line)
        if keep:
            os.write(2, b"".join(keep))


#: The process's one diversion of fd 2 (shared by every MediaPipe detector).
native_stderr = NativeStderr()


def default_model_path() -> Path:
    configured = read_settings().hand_landmarker
    if configured:
        return configured
    return Path(sys.prefix) / "share" / "demoforge" / "hand_landmarker.task"


def _close_quietly(landmarker) -> None:
    try:
        landmarker.close()
    except Exception:  # noqa: BLE001 - closing at shutdown must not raise
        pass


class MediaPipeDetector(HandDetector):
    """MediaPipe Tasks HandLandmarker as a :class:`HandDetector`.

    Args:
        model_path: the .task file (default: :func:`default_model_path`).
        num_hands: maximum hands per frame (2 for bimanual takes).
        min_detection_confidence, min_presence_confidence, min_tracking_confidence: MediaPipe's
            thresholds (palm detector score, hand presence score, tracking IoU in video mode).
        mirrored: the images are selfie-mirrored (swaps the handedness mapping).
        running_mode: "auto" (video for takes, image for single images), "image" (every frame
            independently) or "video" (tracking, also for single images: indices must increase).
        fps: frame rate for video-mode timestamps.
    """

    name = "mediapipe"

    def __init__(self, model_path: str | os.PathLike | None = None, num_hands: int = 2,
                 min_detection_confidence: float = 0.5, min_presence_confidence: float = 0.5,
                 min_tracking_confidence: float = 0.5, mirrored: bool = False,
                 running_mode: str = "auto", fps: float = 30.0):
        try:
            import mediapipe as mp
            from mediapipe.tasks.python import BaseOptions, vision
        except ImportError as e:
            raise DetectorError(
                "the 'mediapipe' hand detector needs the mediapipe package: "
                "pip install --no-deps -r requirements/mediapipe.txt "
                "(then python scripts/fetch_mediapipe_model.py for the model)") from e
        path = Path(model_path) if model_path is not None else default_model_path()
        if not path.is_file():
            raise DetectorError(
                f"MediaPipe hand landmarker model not found at {path}; build it with "
                f"'{sys.executable} scripts/fetch_mediapipe_model.py' (or pass model_path= / set ${MODEL_ENV})")
        if running_mode not in ("auto", "image", "video"):
            raise ValueError(f"running_mode must be 'auto', 'image' or 'video', got {running_mode!r}")
        self._mp = mp
        self.model_path = path
        self.mirrored = bool(mirrored)
        self.running_mode = running_mode
        self.fps = float(fps)
        self.version = f"mediapipe-{getattr(mp, '__version__', '?')}/{path.name}"
        self._vision, self._base_options = vision, BaseOptions
        self._opts = dict(num_hands=int(num_hands), min_hand_detection_confidence=float(min_detection_confidence),
                          min_hand_presence_confidence=float(min_presence_confidence),
                          min_tracking_confidence=float(min_tracking_confidence))
        self._landmarker = self._create("video" if running_mode == "video" else "image")
        self._take_landmarker = None      # "auto": the video-mode tracker of the current take
        self._last_ts = -1
        # Close before interpreter teardown: MediaPipe's close() needs its dispatcher thread pool,
        # which shuts down in threading's exit hooks (before atexit and module teardown).
        self._finalizer = weakref.finalize(self, _close_quietly, self._landmarker)
        self._finalizer.atexit = False
        try:
            threading._register_atexit(self._finalizer)  # runs before concurrent.futures' own hook
        except (AttributeError, RuntimeError):
            self._finalizer.atexit = True

    def _create(self, mode: str):
        vision = self._vision
        opts = vision.HandLandmarkerOptions(
            base_options=self._base_options(model_asset_path=str(self.model_path)),
            running_mode=vision.RunningMode.VIDEO if mode == "video" else vision.RunningMode.IMAGE, **self._opts)
        try:
            with native_stderr.diverted():
                return vision.HandLandmarker.create_from_options(opts)
        except Exception as e:  # noqa: BLE001 - bad model file etc.
            raise DetectorError(f"MediaPipe could not load {self.model_path}: {e}") from e

    def start_take(self) -> None:
        """In "auto" mode: the following frames are one take (tracked in video mode by a fresh
        tracker); in "video" mode: restart the timestamps. No effect in "image" mode."""
        self.end_take()
        if self.running_mode == "auto":
            self._take_landmarker = self._create("video")
        self._last_ts = -1

    def end_take(self) -> None:
        if self._take_landmarker is not None:
            _close_quietly(self._take_landmarker)
            self._take_landmarker = None

    @property
    def tracking(self) -> bool:
        """Whether frames are being tracked (video mode) right now."""
        return self.running_mode == "video" or self._take_landmarker is not None

    def detect_take(self, take, batch_size: int = 16, progress=None):
        self.start_take()
        try:
            return super().detect_take(take, batch_size=batch_size, progress=progress)
        finally:
            self.end_take()

    def close(self) -> None:
        self.end_take()
        fin = getattr(self, "_finalizer", None)
        if fin is not None:
            fin()
        self._landmarker = None

    def _person_hand(self, label: str) -> str:
        raw_left = label.strip().lower() == "left"
        is_left = raw_left if LABEL_IS_PERSON_HAND else not raw_left
        if self.mirrored:
            is_left = not is_left
        return "left" if is_left else "right"

    def detect_image(self, rgb: np.ndarray, K: np.ndarray | None = None,
                     frame_index: int = 0) -> list[HandCandidate]:
        """Candidates of one RGB image (H, W, 3) uint8. Without K, a 60 degree horizontal field of
        view centred on the image is assumed for joints_cam."""
        if self._landmarker is None:
            raise DetectorError("MediaPipeDetector is closed")
        img = np.ascontiguousarray(rgb, dtype=np.uint8)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"rgb must be (H, W, 3) uint8, got {img.shape}")
        h, w = img.shape[:2]
        if K is None:
            f = 0.5 * w / np.tan(np.deg2rad(30.0))
            K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        mp_img = self._mp.Image(image_format=self._mp.ImageFormat.SRGB, data=img)
        if self.tracking:
            ts = int(round(frame_index * 1000.0 / self.fps))
            ts = max(ts, self._last_ts + 1)
            self._last_ts = ts
            lm = self._take_landmarker if self._take_landmarker is not None else self._landmarker
            with native_stderr.diverted():
                res = lm.detect_for_video(mp_img, ts)
        else:
            with native_stderr.diverted():
                res = self._landmarker.detect(mp_img)
        out = []
        for k, lms in enumerate(res.hand_landmarks):
            cat = res.handedness[k][0] if res.handedness and res.handedness[k] else None
            label = cat.category_name if cat is not None else ""
            score = float(cat.score) if cat is not None else 0.0
            px = np.array([[lm.x * w, lm.y * h] for lm in lms], float)
            world = (np.array([[lm.x, lm.y, lm.z] for lm in res.hand_world_landmarks[k]], float)
                     if res.hand_world_landmarks and len(res.hand_world_landmarks) > k else None)
            if world is None or world.shape != (N_JOINTS, 3) or px.shape != (N_JOINTS, 2):
                continue
            t = fit_translation_to_2d(world, px, K)
            cam = world + t
            out.append(HandCandidate(
                handedness=self._person_hand(label), confidence=float(np.clip(score, 0.0, 1.0)),
                joints_px=px, joints_cam=cam,
                extra={"raw_label": label, "world_landmarks": world,
                       "landmark_z": np.array([lm.z for lm in lms], float)}))
        return out

    def detect(self, rgb_batch: np.ndarray, K: np.ndarray,
               frame_indices: Sequence[int]) -> list[list[HandCandidate]]:
        batch, idx = self.image_batch(rgb_batch, frame_indices)
        return [self.detect_image(batch[b], K, idx[b]) for b in range(batch.shape[0])]

