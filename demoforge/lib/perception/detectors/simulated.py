"""The "simulated" backend: HaMeR-like detections made from a synthetic take's ground truth.

OUTPUTS ARE SIMULATED (see lib/perception/simulated_detector.py): every table built from them carries
``detector = "simulated"``. Only synthetic takes (demoforge.lib.synth.take) have the ground truth it needs;
it refuses anything else.

The whole take is simulated at once (the error model is vectorised over time and has temporal
structure: per-take biases, a depth random walk, swap and miss runs), so :meth:`detect` on a batch
returns slices of the same take-wide simulation that :meth:`SimulatedDetector.detect_take` gives.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from demoforge.lib.perception.detectors import N_JOINTS, DetectorError, HandCandidate, HandDetector, HandTrack
from demoforge.lib.perception.simulated_detector import (
    DETECTOR_NAME, SimulatedDetections, SimulatedDetectorConfig, simulate_detections,
)
from demoforge.lib.takes.reader import Take, open_take

__all__ = ["SimulatedDetector", "load_gt_hand_joints"]

VERSION = "1.0.0"


def load_gt_hand_joints(take_dir: str | os.PathLike, n_frames: int | None = None) -> np.ndarray:
    """(T, 2, 21, 3) ground-truth camera-frame joints of a synthetic take; NaN where the hand is
    not in view (``present`` false) or not entirely in front of the camera.

    Raises:
        DetectorError: the take has no ground_truth/gt_hand_joints.parquet (not a synthetic take).
    """
    import pyarrow.parquet as pq

    path = Path(take_dir) / "ground_truth" / "gt_hand_joints.parquet"
    if not path.is_file():
        raise DetectorError(
            f"the 'simulated' hand detector needs ground truth, but {path} does not exist: it only runs "
            f"on synthetic takes made by demoforge.lib.synth.take.generate_take. For a real recording use "
            f"'mediapipe' or 'precomputed' (predictions of an external model)")
    tbl = pq.read_table(path, columns=["frame", "hand", "joints_camera", "present"])
    frame = np.asarray(tbl["frame"].to_numpy(), np.int64)
    hand = np.asarray(tbl["hand"].to_pylist())
    joints = np.asarray(tbl["joints_camera"].to_pylist(), float).reshape(-1, N_JOINTS, 3)
    present = np.asarray(tbl["present"].to_numpy(zero_copy_only=False), bool)
    T = int(frame.max()) + 1 if n_frames is None else int(n_frames)
    out = np.full((T, 2, N_JOINTS, 3), np.nan)
    h = np.where(hand == "left", 0, np.where(hand == "right", 1, -1))
    if np.any(h < 0):
        raise DetectorError(f"{path}: column 'hand' must be 'left' or 'right', got {sorted(set(hand) - {'left', 'right'})}")
    keep = present & (frame < T) & np.all(np.isfinite(joints), axis=(1, 2)) & np.all(joints[..., 2] > 0, axis=1)
    out[frame[keep], h[keep]] = joints[keep]
    return out


class SimulatedDetector(HandDetector):
    """Simulated HaMeR-like detector over a synthetic take's ground truth.

    Args:
        take: the take (demoforge.lib.ingest Take, or a take folder path) whose frames :meth:`detect` sees.
            May be left out and given to :meth:`detect_take` instead.
        config: the error model (default :class:`SimulatedDetectorConfig` ()); ``"zero_noise"`` for
            predictions equal to the ground truth.
        seed: random seed (default: the take's seed from take.json, else config.seed).
        **config_overrides: fields of SimulatedDetectorConfig to change (e.g. ``swap_rate_hz=0``).
    """

    name = DETECTOR_NAME
    version = VERSION

    def __init__(self, take: Any = None, config: SimulatedDetectorConfig | str | None = None,
                 seed: int | None = None, **config_overrides: Any):
        if config == "zero_noise":
            config = SimulatedDetectorConfig.zero_noise()
        cfg = config if config is not None else SimulatedDetectorConfig()
        if config_overrides:
            cfg = cfg.with_(**config_overrides)
        self.config = cfg
        self.seed = seed
        self._take = None
        self._det: SimulatedDetections | None = None
        if take is not None:
            self.bind(take)

    # -- take handling -----------------------------------------------------------------------------
    def bind(self, take: Any) -> "SimulatedDetector":
        """Simulate the whole take now (refuses a take without ground truth)."""
        if not isinstance(take, Take):
            take = open_take(take)
        gt = load_gt_hand_joints(take.meta_dir or take.path, take.n_frames)
        seed = self.seed
        if seed is None:
            seed = take.meta.get("seed", self.config.seed)
        self._take = take
        self._det = simulate_detections(gt, take.camera.K, self.config, seed=int(seed), fps=take.camera.fps)
        return self

    @property
    def detections(self) -> SimulatedDetections:
        if self._det is None:
            raise DetectorError("SimulatedDetector has no take: pass take= or call bind(take) / detect_take(take)")
        return self._det

    def detect_take(self, take: Any = None, batch_size: int = 16, progress=None) -> HandTrack:
        """All frames at once (no image decoding): a HandTrack with the simulator's diagnostics in
        ``extra`` (``injected_swap`` (T,), ``missed`` (T, 2), ``root_depth_scale`` (T, 2))."""
        if take is not None:
            self.bind(take)
        d = self.detections
        n = d.present.shape[0]
        return HandTrack(joints_cam=d.joints_cam.copy(), joints_px=d.joints_px.copy(),
                         confidence=d.confidence.copy(), present=d.present.copy(),
                         n_candidates=d.present.astype(np.int64), detector=self.name,
                         detector_version=self.version,
                         extra={"injected_swap": d.injected_swap.copy(), "missed": d.missed.copy(),
                                "root_depth_scale": d.root_depth_scale.copy(), "n_frames": n})

    def detect(self, rgb_batch: np.ndarray | None, K: np.ndarray,
               frame_indices: Sequence[int]) -> list[list[HandCandidate]]:
        """Candidates of the bound take's frames ``frame_indices`` (the images are not looked at).
        Handedness follows the simulator's (possibly swapped) labels: slot 0 = "left"."""
        d = self.detections
        out = []
        for t in np.asarray(frame_indices, np.int64).tolist():
            if not 0 <= t < d.present.shape[0]:
                raise IndexError(f"frame {t} is outside the bound take ({d.present.shape[0]} frames)")
            cands = []
            for h, side in enumerate(("left", "right")):
                if d.present[t, h]:
                    cands.append(HandCandidate(
                        handedness=side, confidence=float(d.confidence[t, h]), joints_px=d.joints_px[t, h],
                        joints_cam=d.joints_cam[t, h],
                        extra={"injected_swap": bool(d.injected_swap[t]), "simulated": True}))
            out.append(cands)
        return out
