"""Hand detector interface, best-hand selection and the backend registry.

Every backend (MediaPipe, the simulated HaMeR, precomputed predictions, later a torch HaMeR) turns a
batch of RGB frames into per-frame lists of :class:`HandCandidate`; :func:`select_best_hands`
applies the thesis's rule (section 3.1.1: the most confident left candidate and the most confident
right candidate per frame) and returns a vectorised :class:`HandTrack`, which is all that the later
stages (depth alignment, outlier freeze, gripper mapping) see.

Conventions (docs/architecture.md): OpenCV camera frame, metres, pixels; 21 joints in MediaPipe
order; hand/slot 0 = left (the person's left hand), 1 = right.

Adding a backend::

    class MyDetector(HandDetector):
        name = "mine"; version = "1"
        def detect(self, rgb_batch, K, frame_indices): ...  # -> list[list[HandCandidate]]
    register_detector("mine", MyDetector)
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from demoforge.lib.geometry import project_points  # noqa: F401  (re-exported for the backends)
from demoforge.lib.perception.detector_registry import DETECTORS, available_detectors

__all__ = [
    "N_JOINTS",
    "SIDES",
    "HandCandidate",
    "HandTrack",
    "HandDetector",
    "DetectorError",
    "select_best_hands",
    "project_points",
    "fit_translation_to_2d",
    "get_detector",
    "register_detector",
    "available_detectors",
    "DETECTORS",
]

N_JOINTS = 21
SIDES = ("left", "right")


class DetectorError(RuntimeError):
    """A detector cannot run (missing model file, a take without what the backend needs, ...)."""


def fit_translation_to_2d(points_rel: np.ndarray, uv: np.ndarray, K: np.ndarray,
                          weights: np.ndarray | None = None) -> np.ndarray:
    """Translation t so that ``project(points_rel + t, K)`` best fits ``uv`` (linear least squares).

    For each point, ``u (z + tz) = fx (x + tx) + s (y + ty) + cx (z + tz)`` and
    ``v (z + tz) = fy (y + ty) + cy (z + tz)`` are linear in t; the stacked system is solved in the
    least-squares sense (an algebraic, not geometric, error: exact when the fit is exact).

    Args:
        points_rel: (..., N, 3) metric points, up to an unknown translation (camera-aligned axes).
        uv: (..., N, 2) their pixel positions.
        K: (3, 3) intrinsics.
        weights: optional (..., N) non-negative weights per point.

    Returns:
        (..., 3) translations.
    """
    P = np.asarray(points_rel, float)
    q = np.asarray(uv, float)
    K = np.asarray(K, float)
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    x, y, z = P[..., 0], P[..., 1], P[..., 2]
    u, v = q[..., 0], q[..., 1]
    zeros = np.zeros_like(u)
    # rows for u: [fx, s, cx - u] . t = u z - fx x - s y - cx z
    Au = np.stack([np.full_like(u, fx), np.full_like(u, s), cx - u], axis=-1)
    bu = u * z - fx * x - s * y - cx * z
    Av = np.stack([zeros, np.full_like(v, fy), cy - v], axis=-1)
    bv = v * z - fy * y - cy * z
    A = np.concatenate([Au, Av], axis=-2)          # (..., 2N, 3)
    b = np.concatenate([bu, bv], axis=-1)          # (..., 2N)
    if weights is not None:
        w = np.sqrt(np.asarray(weights, float))
        w = np.concatenate([w, w], axis=-1)
        A = A * w[..., None]
        b = b * w
    AtA = np.swapaxes(A, -1, -2) @ A
    Atb = np.swapaxes(A, -1, -2) @ b[..., None]
    return np.linalg.solve(AtA, Atb)[..., 0]


@dataclass
class HandCandidate:
    """One detected hand in one frame.

    ``joints_cam`` is the backend's best estimate of the ABSOLUTE camera-frame joint positions
    (metres, OpenCV frame); ``joints_px`` the 2D keypoints (px, x right / y down) in the full image.
    ``extra`` holds backend-specific diagnostics (raw labels, scores, world landmarks, ...).
    """

    handedness: str
    confidence: float
    joints_px: np.ndarray
    joints_cam: np.ndarray
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.handedness not in SIDES:
            raise ValueError(f"handedness must be 'left' or 'right', got {self.handedness!r}")
        c = float(self.confidence)
        if not (np.isfinite(c) and 0.0 <= c <= 1.0):
            raise ValueError(f"confidence must be in [0, 1], got {self.confidence!r}")
        self.confidence = c
        self.joints_px = np.asarray(self.joints_px, dtype=np.float64).reshape(N_JOINTS, 2)
        self.joints_cam = np.asarray(self.joints_cam, dtype=np.float64).reshape(N_JOINTS, 3)

    @property
    def hand_index(self) -> int:
        return SIDES.index(self.handedness)


@dataclass
class HandTrack:
    """Best left/right hand per frame of a take (slot 0 = left, 1 = right).

    Label every table built from it with ``detector`` (and ``detector_version``).
    """

    joints_cam: np.ndarray      # (T, 2, 21, 3) m, NaN where absent
    joints_px: np.ndarray       # (T, 2, 21, 2) px, NaN where absent
    confidence: np.ndarray      # (T, 2), 0 where absent
    present: np.ndarray         # (T, 2) bool
    n_candidates: np.ndarray    # (T, 2) int: how many candidates of that side the frame had
    detector: str = "unknown"
    detector_version: str = ""
    extra: dict = field(default_factory=dict)  # backend diagnostics, e.g. (T,) arrays

    @property
    def n_frames(self) -> int:
        return int(self.present.shape[0])

    @classmethod
    def empty(cls, n_frames: int, detector: str = "unknown", detector_version: str = "") -> "HandTrack":
        return cls(joints_cam=np.full((n_frames, 2, N_JOINTS, 3), np.nan),
                   joints_px=np.full((n_frames, 2, N_JOINTS, 2), np.nan),
                   confidence=np.zeros((n_frames, 2)), present=np.zeros((n_frames, 2), bool),
                   n_candidates=np.zeros((n_frames, 2), np.int64),
                   detector=detector, detector_version=detector_version)


def select_best_hands(candidates_per_frame: Sequence[Sequence[HandCandidate]] | Mapping[int, Sequence[HandCandidate]],
                      n_frames: int | None = None, *, frame_indices: Sequence[int] | None = None,
                      detector: str = "unknown", detector_version: str = "") -> HandTrack:
    """The thesis's rule: per frame, the left candidate with the highest confidence and the right one.

    Args:
        candidates_per_frame: candidates per frame: a sequence (entry k belongs to frame
            ``frame_indices[k]``, or to frame k when ``frame_indices`` is None) or a mapping
            ``{frame index: candidates}``.
        n_frames: length T of the output (frames without an entry have no hands). Default: one
            more than the largest frame index.
        frame_indices: frame index of each entry of a sequence.

    Ties go to the first candidate. Returns a :class:`HandTrack`.
    """
    if isinstance(candidates_per_frame, Mapping):
        items = [(int(k), v) for k, v in candidates_per_frame.items()]
    else:
        cands = list(candidates_per_frame)
        if frame_indices is None:
            frame_indices = range(len(cands))
        frame_indices = [int(i) for i in frame_indices]
        if len(frame_indices) != len(cands):
            raise ValueError(f"{len(cands)} candidate lists but {len(frame_indices)} frame indices")
        items = list(zip(frame_indices, cands))
    if n_frames is None:
        n_frames = max((i for i, _ in items), default=-1) + 1
    track = HandTrack.empty(int(n_frames), detector, detector_version)
    best = np.full((int(n_frames), 2), -1.0)
    for t, cands in items:
        if not 0 <= t < n_frames:
            raise IndexError(f"frame index {t} out of range for n_frames = {n_frames}")
        for c in cands or ():
            h = c.hand_index
            track.n_candidates[t, h] += 1
            if c.confidence > best[t, h]:
                best[t, h] = c.confidence
                track.joints_cam[t, h] = c.joints_cam
                track.joints_px[t, h] = c.joints_px
                track.confidence[t, h] = c.confidence
                track.present[t, h] = True
    return track


class HandDetector(abc.ABC):
    """Backend-agnostic hand detector. Subclasses set ``name`` / ``version`` and implement detect()."""

    name: str = "abstract"
    version: str = "0"

    @abc.abstractmethod
    def detect(self, rgb_batch: np.ndarray, K: np.ndarray,
               frame_indices: Sequence[int]) -> list[list[HandCandidate]]:
        """Candidates per frame for a batch.

        Args:
            rgb_batch: (B, H, W, 3) uint8, RGB order.
            K: (3, 3) intrinsics of the images.
            frame_indices: (B,) frame index of each image in its take.

        Returns:
            B lists of :class:`HandCandidate` (possibly empty).
        """

    @staticmethod
    def image_batch(rgb_batch: np.ndarray, frame_indices: Sequence[int]) -> tuple[np.ndarray, list[int]]:
        """detect()'s arguments as a (B, H, W, 3) batch (one image is a batch of 1) and B frame indices."""
        batch = np.asarray(rgb_batch)
        if batch.ndim == 3:
            batch = batch[None]
        idx = np.asarray(frame_indices).reshape(-1).tolist()
        if len(idx) != batch.shape[0]:
            raise ValueError(f"{batch.shape[0]} images but {len(idx)} frame indices")
        return batch, idx

    def close(self) -> None:
        """Release resources (models, sessions). Safe to call twice."""

    def __enter__(self) -> "HandDetector":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def detect_take(self, take: Any, batch_size: int = 16,
                    progress: Callable[[int, int], None] | None = None) -> HandTrack:
        """Run over a whole take (demoforge.lib.ingest Take) and select the best hands per frame.

        Frames whose RGB cannot be read have no hands (and are flagged on ``take.frames``).
        """
        from demoforge.lib.takes.reader import iter_frames  # lazy (CLI --help)

        per_frame: dict[int, list[HandCandidate]] = {}
        done = 0
        for batch in iter_frames(take, batch_size=batch_size):
            out = self.detect(batch.rgb, take.camera.K, batch.indices)
            for i, c in zip(batch.indices.tolist(), out):
                per_frame[i] = c
            done += len(batch.indices)
            if progress is not None:
                progress(done, take.n_frames)
        return select_best_hands(per_frame, take.n_frames, detector=self.name, detector_version=self.version)


# ------------------------------------------------------------------------------------------------
# registry
# ------------------------------------------------------------------------------------------------

def register_detector(name: str, factory: Callable[..., HandDetector] | str) -> None:
    """Register a backend: a callable returning a HandDetector, or a lazy "module:attribute" string."""
    DETECTORS.register(name, factory)


def get_detector(name: str, **options: Any) -> HandDetector:
    """Build a detector by name ("mediapipe", "simulated", "precomputed", "hamer", or a registered one)."""
    return DETECTORS.get(name)(**options)
