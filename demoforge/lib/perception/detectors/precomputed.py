"""The "precomputed" backend: predictions made elsewhere (HaMeR on a GPU box, the thesis's code, any model).

Accepted files (by extension):

* ``.json`` -- the thesis code's keypoint JSON (Jiayun-Zhang/Hand_keypoint_detector ``run.py``), see
  :func:`demoforge.lib.takes.reader.read_thesis_keypoints_json`: ``{"<image name>": {"left": {...} | {} |
  null, "right": ...}}`` with ``3d_keypoints`` (21x3, relative), ``translation`` (3, HaMeR's
  ``pred_cam_t_full``), ``2d_keypoints`` (21x2) and ``focal_length``. joints_cam = 3d_keypoints +
  translation. That file has no confidence: 1.0 is used (or the entry's ``confidence`` if present).
  Its 2D keypoints were projected with K = [[f, 0, 320], [0, f, 240], [0, 0, 1]]: they are used as
  they are unless ``reproject_2d=True`` (then joints_cam is projected with the take's K).

* ``.parquet`` -- one row per candidate hand:

  ==============  ================================  =========================================
  column          type                              meaning
  ==============  ================================  =========================================
  frame           int                               0-based frame index (required)
  hand            str "left"/"right" or int 0/1     handedness (required)
  joints_cam      21x3 (nested list or 63 floats)   camera-frame joints, m (required)
  joints_px       21x2 (nested list or 42 floats)   2D keypoints, px (optional: else projected with K)
  confidence      float in [0, 1]                   (optional: default 1.0)
  ==============  ================================  =========================================

  Several rows for the same (frame, hand) are candidates; :func:`select_best_hands` keeps the most
  confident. ``joints_camera`` is accepted as an alias of ``joints_cam`` (the gt_* tables' name).

* ``.npz`` -- either the same row layout (arrays ``frame`` (N,), ``hand`` (N,), ``joints_cam``
  (N, 21, 3), optional ``joints_px`` (N, 21, 2), ``confidence`` (N,)), or a per-frame track
  (``joints_cam`` (T, 2, 21, 3) with NaN for absent hands, optional ``joints_px`` (T, 2, 21, 2),
  ``confidence`` (T, 2), ``present`` (T, 2), ``frame`` (T,) frame indices, default 0..T-1).

:func:`write_predictions` writes a :class:`HandTrack` or candidate lists in the Parquet/NPZ layout.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from demoforge.lib.perception.detectors import (
    N_JOINTS, SIDES, DetectorError, HandCandidate, HandDetector, HandTrack, project_points,
    select_best_hands,
)
from demoforge.lib.takes.reader import TakeError
from demoforge.lib.takes.thesis_json import read_thesis_keypoints_json

__all__ = ["PrecomputedDetector", "load_predictions", "write_predictions"]

VERSION = "1.0.0"


def _hand_index(v: Any, where: str) -> int:
    if isinstance(v, bytes):
        v = v.decode()
    if isinstance(v, str):
        s = v.strip().lower()
        if s in ("left", "l"):
            return 0
        if s in ("right", "r"):
            return 1
    elif isinstance(v, (int, np.integer)) and int(v) in (0, 1):
        return int(v)
    raise DetectorError(f"{where}: hand must be 'left'/'right' or 0/1, got {v!r}")


def _as_joints(x: Any, n: int, dim: int, name: str, path: Path) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise DetectorError(f"{path}: column {name!r} must hold {N_JOINTS}x{dim} numbers ({e})") from e
    try:
        return a.reshape(n, N_JOINTS, dim)
    except ValueError as e:
        raise DetectorError(f"{path}: column {name!r} must hold {N_JOINTS}x{dim} numbers per row, "
                            f"got shape {a.shape}") from e


def _rows_to_candidates(path: Path, frame, hand, joints_cam, joints_px, confidence, K,
                        source: str) -> dict[int, list[HandCandidate]]:
    n = len(frame)
    jc = _as_joints(joints_cam, n, 3, "joints_cam", path)
    jp = _as_joints(joints_px, n, 2, "joints_px", path) if joints_px is not None else None
    conf = np.ones(n) if confidence is None else np.asarray(confidence, float).reshape(n)
    if jp is None:
        if K is None:
            raise DetectorError(f"{path}: no joints_px given; pass K (or a take) so they can be projected")
        jp = project_points(jc, K)
    out: dict[int, list[HandCandidate]] = {}
    for i in range(n):
        f = int(frame[i])
        if f < 0:
            raise DetectorError(f"{path}: row {i} has negative frame {f}")
        if not np.all(np.isfinite(jc[i])):
            continue                       # an absent hand written as NaN
        c = float(conf[i]) if np.isfinite(conf[i]) else 0.0
        if not 0.0 <= c <= 1.0:
            raise DetectorError(f"{path}: row {i} has confidence {c}, must be in [0, 1]")
        h = _hand_index(hand[i], f"{path} row {i}")
        out.setdefault(f, []).append(HandCandidate(SIDES[h], c, jp[i], jc[i], extra={"source": source}))
    return out


def load_predictions(path: str | os.PathLike, *, K: np.ndarray | None = None, take: Any = None,
                     reproject_2d: bool = False) -> dict[int, list[HandCandidate]]:
    """Read a predictions file (see the module docstring) into ``{frame index: [HandCandidate]}``.

    ``K`` (or ``take.camera.K``) projects joints_cam where no 2D keypoints are given (and for
    ``reproject_2d``); ``take`` maps the thesis JSON's image names to frame indices.
    """
    p = Path(path)
    if not p.is_file():
        raise DetectorError(f"predictions file {p} does not exist")
    if K is None and take is not None:
        K = take.camera.K
    suffix = p.suffix.lower()
    if suffix == ".json":
        try:
            hands = read_thesis_keypoints_json(p, take=take)
        except TakeError as e:
            raise DetectorError(str(e)) from e
        out: dict[int, list[HandCandidate]] = {}
        for h in hands:
            px = h.joints_px
            if px is None or reproject_2d:
                if K is None:
                    raise DetectorError(f"{p}: {h.image}.{h.hand} needs K to project its 2D keypoints")
                px = project_points(h.joints_cam, K)
            conf = 1.0 if h.confidence is None else h.confidence
            out.setdefault(h.frame, []).append(HandCandidate(
                h.hand, conf, px, h.joints_cam,
                extra={"source": "thesis_json", "image": h.image, "translation": h.translation,
                       "focal_length": h.focal_length}))
        return out
    if suffix == ".parquet":
        import pyarrow.parquet as pq

        tbl = pq.read_table(p)
        cols = set(tbl.column_names)
        jc_name = "joints_cam" if "joints_cam" in cols else ("joints_camera" if "joints_camera" in cols else None)
        missing = [c for c, ok in (("frame", "frame" in cols), ("hand", "hand" in cols),
                                   ("joints_cam", jc_name is not None)) if not ok]
        if missing:
            raise DetectorError(f"{p}: missing column(s) {missing}; need frame, hand, joints_cam "
                                f"(optional joints_px, confidence); has {sorted(cols)}")
        get = lambda c: tbl[c].to_pylist() if c in cols else None  # noqa: E731
        jp = get("joints_px")
        if reproject_2d:
            jp = None
        return _rows_to_candidates(p, get("frame"), get("hand"), get(jc_name), jp, get("confidence"), K, "parquet")
    if suffix == ".npz":
        z = np.load(p, allow_pickle=False)
        keys = set(z.files)
        if "joints_cam" not in keys:
            raise DetectorError(f"{p}: needs array 'joints_cam' ((N, 21, 3) rows or (T, 2, 21, 3) track); "
                                f"has {sorted(keys)}")
        jc = z["joints_cam"]
        get = lambda c: z[c] if c in keys else None  # noqa: E731
        jp = None if reproject_2d else get("joints_px")
        if jc.ndim == 4:                                # track layout
            T = jc.shape[0]
            if jc.shape[1:] != (2, N_JOINTS, 3):
                raise DetectorError(f"{p}: track joints_cam must be (T, 2, 21, 3), got {jc.shape}")
            frames = get("frame")
            frames = np.arange(T) if frames is None else np.asarray(frames).reshape(T)
            present = get("present")
            present = np.all(np.isfinite(jc), axis=(2, 3)) if present is None else np.asarray(present, bool)
            conf = get("confidence")
            conf = np.ones((T, 2)) if conf is None else np.asarray(conf, float)
            tt, hh = np.nonzero(present)
            return _rows_to_candidates(
                p, frames[tt], hh, jc[tt, hh], None if jp is None else np.asarray(jp)[tt, hh],
                conf[tt, hh], K, "npz")
        for c in ("frame", "hand"):
            if c not in keys:
                raise DetectorError(f"{p}: row layout needs arrays 'frame' and 'hand' with joints_cam (N, 21, 3)")
        return _rows_to_candidates(p, z["frame"], z["hand"].tolist(), jc, jp, get("confidence"), K, "npz")
    raise DetectorError(f"{p}: unsupported predictions file type {suffix!r}; use .json (thesis code), "
                        f".parquet or .npz")


def write_predictions(path: str | os.PathLike,
                      predictions: HandTrack | Mapping[int, Sequence[HandCandidate]]) -> Path:
    """Write predictions in the row layout (.parquet or .npz); one row per candidate / present hand."""
    p = Path(path)
    rows_f, rows_h, rows_c, rows_p, rows_s = [], [], [], [], []
    if isinstance(predictions, HandTrack):
        tt, hh = np.nonzero(predictions.present)
        rows_f, rows_h = tt.tolist(), [SIDES[h] for h in hh]
        rows_c = predictions.joints_cam[tt, hh]
        rows_p = predictions.joints_px[tt, hh]
        rows_s = predictions.confidence[tt, hh]
    else:
        for f in sorted(predictions):
            for c in predictions[f]:
                rows_f.append(int(f))
                rows_h.append(c.handedness)
                rows_c.append(c.joints_cam)
                rows_p.append(c.joints_px)
                rows_s.append(c.confidence)
    jc = np.asarray(rows_c, float).reshape(-1, N_JOINTS, 3)
    jp = np.asarray(rows_p, float).reshape(-1, N_JOINTS, 2)
    conf = np.asarray(rows_s, float).reshape(-1)
    frame = np.asarray(rows_f, np.int64)
    p.parent.mkdir(parents=True, exist_ok=True)
    if p.suffix.lower() == ".npz":
        np.savez(p, frame=frame, hand=np.asarray(rows_h, dtype="U5"), joints_cam=jc, joints_px=jp,
                 confidence=conf)
    elif p.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        def nested(a: np.ndarray, d: int) -> pa.Array:
            inner = pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), d)
            return pa.FixedSizeListArray.from_arrays(inner, N_JOINTS)

        tbl = pa.table({"frame": pa.array(frame, pa.int64()), "hand": pa.array(rows_h, pa.string()),
                        "joints_cam": nested(jc, 3), "joints_px": nested(jp, 2),
                        "confidence": pa.array(conf, pa.float64())})
        pq.write_table(tbl, p)
    else:
        raise DetectorError(f"{p}: write .parquet or .npz")
    return p


class PrecomputedDetector(HandDetector):
    """Serve predictions from a file as a detector.

    Args:
        path: predictions file (.json thesis format, .parquet, .npz; see the module docstring).
        take: optional take (maps the thesis JSON's image names to frames; gives K).
        K: intrinsics for projecting joints_cam when a file has no 2D keypoints.
        reproject_2d: ignore the file's 2D keypoints and project joints_cam with K instead.
        name: the ``detector`` label for tables (default "precomputed"; e.g. "hamer").
    """

    version = VERSION

    def __init__(self, path: str | os.PathLike, take: Any = None, K: np.ndarray | None = None,
                 reproject_2d: bool = False, name: str = "precomputed"):
        self.path = Path(path)
        self.name = name
        self._take = take
        self._K = K
        self._reproject = reproject_2d
        self._cands: dict[int, list[HandCandidate]] | None = None
        self._cands_K: Any = None
        # fail early on a bad file when the 2D keypoints need no K
        self._load(K if K is not None else (take.camera.K if take is not None else None), lazy_ok=True)

    def _load(self, K: np.ndarray | None, lazy_ok: bool = False) -> dict[int, list[HandCandidate]]:
        key = None if K is None else np.asarray(K, float).tobytes()
        if self._cands is None or (self._cands_K != key and key is not None):
            try:
                self._cands = load_predictions(self.path, K=K, take=self._take, reproject_2d=self._reproject)
                self._cands_K = key
            except DetectorError as e:
                if lazy_ok and K is None and "K" in str(e):
                    return {}
                raise
        return self._cands

    def candidates(self) -> dict[int, list[HandCandidate]]:
        return self._load(self._K if self._K is not None else (self._take.camera.K if self._take is not None else None))

    def detect(self, rgb_batch: np.ndarray | None, K: np.ndarray,
               frame_indices: Sequence[int]) -> list[list[HandCandidate]]:
        cands = self._load(self._K if self._K is not None else K)
        return [list(cands.get(int(i), [])) for i in np.asarray(frame_indices).tolist()]

    def detect_take(self, take: Any = None, batch_size: int = 16, progress=None) -> HandTrack:
        """All frames of the take from the file (no image decoding)."""
        take = take if take is not None else self._take
        if take is None:
            raise DetectorError("PrecomputedDetector.detect_take needs a take (for the frame count and K)")
        if self._take is None:
            self._take = take
            self._cands = None
        cands = self._load(self._K if self._K is not None else take.camera.K)
        beyond = [f for f in cands if f >= take.n_frames]
        if beyond:
            raise DetectorError(f"{self.path}: predictions for frame {min(beyond)}.. but the take has "
                                f"{take.n_frames} frames; wrong file for this take?")
        return select_best_hands(cands, take.n_frames, detector=self.name, detector_version=self.version)
