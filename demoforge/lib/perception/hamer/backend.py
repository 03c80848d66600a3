"""The "hamer" hand detector backend: HaMeR in torch on hand boxes, without a person detector or ViTPose.

The thesis's simplified HaMeR (one operator): hand boxes come from

* ``box_source="previous"``: the previous frame's keypoints of the same hand (tracking); a hand
  without a usable previous frame (the first frame, or after it was lost) gets its box from
  ``initial_boxes`` or, with ``fallback="mediapipe"``, from MediaPipe's detection in that frame;
* ``box_source="mediapipe"``: MediaPipe's hand detections in every frame (their handedness too).

Each box is cropped (left hands flipped), run through the network and MANO, and un-flipped; the
crop camera is moved to the take's intrinsics (demoforge.lib.perception.hamer.camera). HaMeR has no confidence output:
a candidate's confidence is its box source's confidence (MediaPipe's handedness score; 1 for a
tracked or given box) times the fraction of its 2D keypoints inside the crop square, so a hand
that drifts out of its box loses to a better candidate and a track with confidence below
``min_track_confidence`` is dropped. :func:`demoforge.lib.perception.detectors.select_best_hands` then keeps the most
confident left and right hand per frame.

Loaded models are cached per (checkpoint, MANO file, device, config): a second take, or a second
detector instance, reuses the network already in memory.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from demoforge.lib.perception.detectors import DetectorError, HandCandidate, HandDetector, SIDES
from demoforge.lib.perception.detectors.mediapipe_backend import MediaPipeDetector
from demoforge.lib.perception.hamer.camera import box_from_keypoints
from demoforge.lib.perception.hamer.checkpoint import CheckpointError, load_hamer
from demoforge.lib.perception.hamer.mano import MANOError
from demoforge.lib.perception.hamer.model import HamerConfig, HamerPredictor, default_device

__all__ = ["HamerDetector", "get_predictor", "clear_predictor_cache"]

_CACHE: dict[tuple, HamerPredictor] = {}
_CACHE_LOCK = threading.Lock()


def _file_key(p: str | os.PathLike) -> tuple:
    path = Path(p).expanduser().resolve()
    st = path.stat()
    return str(path), st.st_size, st.st_mtime_ns


def get_predictor(checkpoint: str | os.PathLike, mano_model: str | os.PathLike, device: str | None = None,
                  config: HamerConfig | None = None, **options: Any) -> HamerPredictor:
    """A loaded :class:`HamerPredictor`, shared by every detector with the same files and device."""
    for what, p, flag in (("HaMeR checkpoint", checkpoint, "--hamer-checkpoint"), ("MANO model", mano_model, "--mano-model")):
        if p is None or not Path(p).expanduser().is_file():
            raise DetectorError(f"the 'hamer' detector needs the {what} file ({flag} PATH); not found: {p}")
    dev = str(device) if device else str(default_device())
    key = (_file_key(checkpoint), _file_key(mano_model), dev, config, tuple(sorted(options.items())))
    with _CACHE_LOCK:
        pred = _CACHE.get(key)
        if pred is None:
            try:
                net, _ = load_hamer(checkpoint, config)
                pred = HamerPredictor(net, mano_model, device=dev, **options)
            except (CheckpointError, MANOError) as e:
                raise DetectorError(str(e)) from e
            _CACHE[key] = pred
    return pred


def clear_predictor_cache() -> None:
    with _CACHE_LOCK:
        _CACHE.clear()


class HamerDetector(HandDetector):
    """HaMeR as a :class:`HandDetector` (see the module docstring).

    Args:
        checkpoint: local path of ``hamer.ckpt``.
        mano_model: local path of ``MANO_RIGHT.pkl`` (or an .npz with its arrays).
        box_source: "previous" or "mediapipe".
        fallback: for "previous": "mediapipe" (detect a hand that has no track) or "none".
        initial_boxes: for "previous": {"left"/"right": (x0, y0, x1, y1)} seeding the first frame.
        device: "cuda", "cpu" or None (cuda when present).
        batch_size: crops per forward pass.
        rescale_factor: box padding as HaMeR's demo (2.0).
        translation: "crop_camera" or "fit_2d" (demoforge.lib.perception.hamer.model.HamerPredictor).
        min_track_confidence: a tracked hand below this is dropped (re-detected via the fallback).
        config: network sizes (default: the released model).
        mediapipe_options: keyword arguments of MediaPipeDetector.
    """

    name = "hamer"

    def __init__(self, checkpoint: str | os.PathLike, mano_model: str | os.PathLike, box_source: str = "previous",
                 fallback: str = "mediapipe", initial_boxes: Mapping[str, Sequence[float]] | None = None,
                 device: str | None = None, batch_size: int = 16, rescale_factor: float = 2.0,
                 translation: str = "crop_camera", min_track_confidence: float = 0.5,
                 config: HamerConfig | None = None, mediapipe_options: Mapping[str, Any] | None = None,
                 amp: bool = False):
        if box_source not in ("previous", "mediapipe"):
            raise ValueError(f"box_source must be 'previous' or 'mediapipe', got {box_source!r}")
        if fallback not in ("mediapipe", "none"):
            raise ValueError(f"fallback must be 'mediapipe' or 'none', got {fallback!r}")
        if initial_boxes:
            bad = [k for k in initial_boxes if k not in SIDES]
            if bad:
                raise ValueError(f"initial_boxes keys must be 'left'/'right', got {bad}")
        self.predictor = get_predictor(checkpoint, mano_model, device, config, batch_size=batch_size,
                                       rescale_factor=rescale_factor, translation=translation, amp=amp)
        self.box_source = box_source
        self.fallback = fallback
        self.initial_boxes = {k: np.asarray(v, float).reshape(4) for k, v in (initial_boxes or {}).items()}
        self.min_track_confidence = float(min_track_confidence)
        self._mp_options = dict(mediapipe_options or {})
        self._mp = None
        self.version = f"hamer-torch-1/{Path(checkpoint).name}/{box_source}"
        self.reset()

    # -- state -----------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the tracked boxes (a new take starts from initial_boxes / the fallback)."""
        self._track: dict[str, np.ndarray | None] = {s: None for s in SIDES}
        self._seeded = False

    def close(self) -> None:
        if self._mp is not None:
            self._mp.close()
            self._mp = None

    def detect_take(self, take, batch_size: int = 16, progress=None):
        self.reset()
        return super().detect_take(take, batch_size=batch_size, progress=progress)

    def _mediapipe(self):
        if self._mp is None:
            self._mp = MediaPipeDetector(**self._mp_options)
        return self._mp

    # -- detection -------------------------------------------------------------------------------
    def _run(self, images: np.ndarray, K: np.ndarray, boxes: list[tuple[int, str, np.ndarray, float, str]]
             ) -> list[list[HandCandidate]]:
        """boxes: (image index, side, xyxy, source confidence, source name) -> candidates per image."""
        out: list[list[HandCandidate]] = [[] for _ in range(len(images))]
        if not boxes:
            return out
        idx = np.array([b[0] for b in boxes])
        right = np.array([b[1] == "right" for b in boxes])
        xyxy = np.stack([b[2] for b in boxes])
        pred = self.predictor.predict(images, xyxy, idx, right, K)
        half = pred.box_size[:, None] / 2
        inside = np.all(np.abs(pred.joints_px - pred.box_center[:, None]) <= half[..., None], axis=-1).mean(-1)
        finite = np.isfinite(pred.joints_cam).all(axis=(1, 2)) & np.isfinite(pred.joints_px).all(axis=(1, 2))
        for k, (i, side, box, src_conf, src) in enumerate(boxes):
            if not finite[k]:
                continue
            out[i].append(HandCandidate(
                handedness=side, confidence=float(np.clip(src_conf * inside[k], 0.0, 1.0)),
                joints_px=pred.joints_px[k], joints_cam=pred.joints_cam[k],
                extra={"box": box, "box_source": src, "in_box_fraction": float(inside[k]),
                       "cam_crop": pred.cam_crop[k], "betas": pred.betas[k],
                       "translation": pred.translation[k]}))
        return out

    def _mediapipe_boxes(self, rgb: np.ndarray, K: np.ndarray, frame_index: int, sides: Sequence[str]):
        cands = self._mediapipe().detect_image(rgb, K, frame_index)
        best: dict[str, HandCandidate] = {}
        for c in cands:
            if c.handedness in sides and (c.handedness not in best or c.confidence > best[c.handedness].confidence):
                best[c.handedness] = c
        return {s: (box_from_keypoints(c.joints_px), c.confidence) for s, c in best.items()}

    def detect(self, rgb_batch: np.ndarray, K: np.ndarray, frame_indices: Sequence[int]) -> list[list[HandCandidate]]:
        batch, idx = self.image_batch(rgb_batch, frame_indices)
        if self.box_source == "mediapipe":
            boxes = []
            for b in range(batch.shape[0]):  # every MediaPipe hand becomes a HaMeR crop; one network batch
                for c in self._mediapipe().detect_image(batch[b], K, idx[b]):
                    boxes.append((b, c.handedness, box_from_keypoints(c.joints_px), c.confidence, "mediapipe"))
            return self._run(batch, K, boxes)
        # "previous": frame t's boxes come from frame t-1's result, so frames run one after another
        results = []
        for b in range(batch.shape[0]):
            boxes = []
            if not self._seeded:
                for s, box in self.initial_boxes.items():
                    self._track[s] = box
                self._seeded = True
            missing = [s for s in SIDES if self._track[s] is None]
            for s in SIDES:
                if self._track[s] is not None:
                    boxes.append((0, s, self._track[s], 1.0, "previous"))
            if missing and self.fallback == "mediapipe":
                for s, (box, conf) in self._mediapipe_boxes(batch[b], K, idx[b], missing).items():
                    boxes.append((0, s, box, conf, "mediapipe"))
            cands = self._run(batch[b:b + 1], K, boxes)[0]
            for s in SIDES:
                mine = [c for c in cands if c.handedness == s]
                best = max(mine, key=lambda c: c.confidence, default=None)
                self._track[s] = (box_from_keypoints(best.joints_px)
                                  if best is not None and best.confidence >= self.min_track_confidence else None)
            results.append(cands)
        return results
