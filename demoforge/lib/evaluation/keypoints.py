"""Hand keypoint evaluation rows and the thesis's tables and figures (sections 4.2, 5.1, Appendix B).

:func:`evaluate_take` turns one take's predictions and ground truth into one row per hand (plain
dicts; the lead writes them to the ``keypoint_metrics`` table). The metrics are demoforge.lib.evaluation.metrics's,
computed over the frames where the hand is ground-truth valid AND detected (the thesis's N samples,
eq. 4-7); the detection rate is reported beside them:

* ``mpjpe_m`` -- eq. (4) on the raw camera-frame prediction.
* ``mpjpe_aligned_m`` -- eq. (4) after the ingest's depth alignment (demoforge.lib.ingest.alignment.align_to_depth).
  ARCTIC has no depth camera, so the depth of each anchor joint is taken from the GROUND TRUTH:
  ``anchor_depth`` = the ground-truth camera z of the anchor joints (the thesis's "true 3D position
  in the depth image"). With the GT depth at the joint centre the skin-to-joint offset
  (``surface_offset_m``) is 0. The row's ``note`` and ``anchor_depth_source`` say so. Synthetic takes
  (:func:`evaluate_synthetic_take`) read their real rendered depth maps instead.
* ``pa_mpjpe_m`` / ``pa_mpjpe_aligned_m`` -- eq. (5), similarity Procrustes per sample.
* ``rr_mpjpe_m`` -- root-relative MPJPE (wrist subtracted; ARCTIC's papers' convention).
* ``mpjpe_2d_px``, ``pck05``, ``pck15`` -- eq. (6), (7): the 3D prediction projected with the
  camera's K (thesis 4.2.2), against the ground-truth 2D joints; PCK normalised by the ground-truth
  hand box size (max side of the tight box of the GT 2D joints, demoforge.lib.evaluation.metrics.bbox_size).
  ``*_aligned_*``: the same for the aligned prediction (Figure 20b speaks of "MPJPE after
  alignment"); ``*_pred_*``: the detector's own 2D keypoints when given.

Tables 1, 2 and Appendix B are SQL views over `keypoint_metrics` (schemas/reports.py: report_table1,
report_table2, report_appendix_b); here, as lists of dicts: :func:`per_object` (Figures 19-20) and
:func:`big_vs_small` (Figure 21). The thesis's Table 1/2 values
are NOT the plain mean over takes of its Appendix B (e.g. left MPJPE: mean of the 18 takes 1.296 vs
Table 1's 1.301; left aligned 0.0224 vs 0.024), which fits eq. (4)'s pooling over all N frames;
``weighting="frames"`` (default) weights each take by its evaluated frames, ``weighting="takes"``
is the plain mean over takes.

Big vs small objects (thesis 4.2 and 5.1.1): big = box, capsule (coffee) machine, espresso machine;
small = ketchup bottle, phone, scissors.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from demoforge.lib import SHARED_DATA
from demoforge.lib.evaluation import real_photos as rpe
from demoforge.lib.evaluation.metrics import mpjpe, mpjpe_2d, pa_mpjpe, pck, root_relative_mpjpe
from demoforge.lib.ingest.alignment import AlignmentConfig, align_to_depth, read_depth_robust
from demoforge.lib.perception.detectors import get_detector
from demoforge.lib.perception.detectors.mediapipe_backend import MediaPipeDetector
from demoforge.lib.takes import iter_depth, open_take

__all__ = [
    "BIG_OBJECTS", "SMALL_OBJECTS", "OBJECT_LABELS", "APPENDIX_B_ORDER", "APPENDIX_B_SECTIONS",
    "GT_ANCHOR_NOTE", "size_group", "gt_anchor_depth", "project_per_frame", "common_K", "evaluate_take",
    "evaluate_arctic_take", "evaluate_synthetic_take", "real_photo_rows", "evaluate_real_photos",
    "per_object", "big_vs_small", "plot_per_take_bars",
    "plot_per_object_bars", "plot_big_vs_small", "format_markdown",
]

#: Thesis section 4.2: "three large objects: boxes, capsule coffee machines, and espresso machines,
#: and three small objects: ketchup bottles, mobile phones, and scissors".
BIG_OBJECTS: tuple[str, ...] = ("box", "capsulemachine", "espressomachine")
SMALL_OBJECTS: tuple[str, ...] = ("ketchup", "phone", "scissors")
OBJECT_LABELS = {"box": "box", "capsulemachine": "capsule machine", "espressomachine": "espresso machine",
                 "ketchup": "ketchup bottle", "phone": "phone", "scissors": "scissors"}
#: Take order of the thesis's Appendix B tables.
APPENDIX_B_ORDER: tuple[str, ...] = (
    "scissors_use_02", "box_grab_01", "box_use_01", "box_use_02", "capsulemachine_use_01",
    "capsulemachine_use_02", "capsulemachine_grab_01", "espressomachine_grab_01", "espressomachine_use_01",
    "espressomachine_use_02", "ketchup_grab_01", "ketchup_use_01", "ketchup_use_02", "phone_grab_01",
    "phone_use_01", "phone_use_02", "scissors_use_01", "scissors_grab_01",
)
#: Appendix B's three sub-tables: (title, columns of the report_appendix_b view's rows).
APPENDIX_B_SECTIONS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("MPJPE (m)", ("take", "mpjpe_left", "mpjpe_left_aligned", "mpjpe_right", "mpjpe_right_aligned")),
    ("PA-MPJPE (m)", ("take", "pa-mpjpe_left", "pa-mpjpe_left_aligned", "pa-mpjpe_right", "pa-mpjpe_right_aligned")),
    ("2D (px, PCK)", ("take", "2D_mpjpe_r", "2D_mpjpe_l", "pck05_r", "pck15_r", "pck05_l", "pck15_l")),
)
GT_ANCHOR_NOTE = ("aligned metrics: anchor depth taken from the ground-truth camera z of the anchor "
                  "joints (the dataset has no depth camera), surface offset 0")
SIDES = ("left", "right")
HAND_LABEL = {"left": "Left Hand", "right": "Right Hand"}


def size_group(obj: str | None) -> str | None:
    """'big' / 'small' as in the thesis, None for other objects."""
    if obj in BIG_OBJECTS:
        return "big"
    if obj in SMALL_OBJECTS:
        return "small"
    return None


# --------------------------------------------------------------------------- camera helpers


def project_per_frame(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Project (T, ..., 3) camera-frame points with K (3, 3) or per frame (T, 3, 3) -> (T, ..., 2);
    NaN behind the camera."""
    p = np.asarray(points, np.float64)
    K = np.asarray(K, np.float64)
    if K.ndim == 2:
        uvw = p @ K.T
    else:
        Kb = K.reshape((K.shape[0],) + (1,) * (p.ndim - 2) + (3, 3))
        uvw = np.einsum("...ij,...j->...i", Kb, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[..., :2] / uvw[..., 2:3]
    return np.where(p[..., 2:3] > 0, uv, np.nan)


def common_K(K: np.ndarray, px: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """A single K for a per-frame (T, 3, 3) K (ARCTIC's egocentric camera): the first frame's K0,
    and pixel coordinates (T, ..., 2) remapped to it, ``u' = K0 K_t^-1 [u, 1]`` (exact for a pinhole:
    the same rays, so camera-frame 3D points are unchanged). (3, 3) K passes through."""
    K = np.asarray(K, np.float64)
    if K.ndim == 2:
        return K, px
    K0 = K[0]
    if px is None or np.allclose(K, K0[None], rtol=0, atol=1e-9):
        return K0, px
    M = np.einsum("ij,tjk->tik", K0, np.linalg.inv(K))           # (T, 3, 3)
    q = np.asarray(px, np.float64)
    qh = np.concatenate([q, np.ones(q.shape[:-1] + (1,))], -1)
    Mb = M.reshape((M.shape[0],) + (1,) * (q.ndim - 2) + (3, 3))
    r = np.einsum("...ij,...j->...i", Mb, qh)
    return K0, r[..., :2] / r[..., 2:3]


def gt_anchor_depth(pred_cam, gt_cam, K, anchors, pred_px=None, gt_px=None, valid=None) -> np.ndarray:
    """(T, 2, A) ground-truth depth for the anchors of each PREDICTED slot, as a depth camera would
    read it: the ground-truth camera z of the anchor joints of the ground-truth hand that the
    prediction lies on in the image (nearest 2D centroid; a left/right swap of the detector then
    reads the other hand's depth, as with a real depth map). NaN where the slot has no prediction or
    no valid ground-truth hand."""
    P = np.asarray(pred_cam, np.float64)
    G = np.asarray(gt_cam, np.float64)
    T = G.shape[0]
    anchors = np.asarray(anchors)
    p2 = project_per_frame(P, K) if pred_px is None else np.asarray(pred_px, np.float64)
    g2 = project_per_frame(G, K) if gt_px is None else np.asarray(gt_px, np.float64)
    ok_g = np.isfinite(G).all(axis=(2, 3)) & np.isfinite(g2).all(axis=(2, 3))
    if valid is not None:
        ok_g &= np.asarray(valid, bool)
    okp = np.isfinite(p2).all(-1)                                                 # (T, 2, 21)
    cnt = okp.sum(-1)
    cp = np.where(okp[..., None], p2, 0.0).sum(2) / np.maximum(cnt, 1)[..., None]  # (T, 2, 2) predicted slots
    cp = np.where((cnt > 0)[..., None], cp, np.nan)
    cg = np.where(ok_g[..., None], g2.mean(axis=2), np.nan)                        # (T, 2, 2) GT hands
    d = np.linalg.norm(cp[:, :, None, :] - cg[:, None, :, :], axis=-1)           # (T, slot, gt hand)
    d = np.where(np.isfinite(d), d, np.inf)
    which = np.argmin(d, axis=-1)                                                 # (T, 2)
    has = np.isfinite(np.min(d, axis=-1))
    z = G[:, :, anchors, 2]                                                       # (T, gt hand, A)
    out = z[np.arange(T)[:, None], which]                                         # (T, slot, A)
    return np.where(has[..., None], out, np.nan)


def _resolve_config(alignment_config) -> tuple[AlignmentConfig, str]:
    if alignment_config is None or alignment_config == "default":
        # ground-truth anchor depth: at the joint centre (no skin offset) and never occluded (the
        # temporal depth-outlier check, made for occluded readings, would only reject real motion)
        return (AlignmentConfig(surface_offset_m=0.0, depth_outlier_m=None),
                "default(surface_offset_m=0,depth_outlier_m=None)")
    if alignment_config == "thesis":
        return AlignmentConfig.thesis(), "thesis"
    if isinstance(alignment_config, AlignmentConfig):
        return alignment_config, "custom"
    raise ValueError(f"alignment_config must be None, 'default', 'thesis' or an AlignmentConfig, got {alignment_config!r}")


def _f(x) -> float:
    return float(x) if x is not None and np.isfinite(x) else float("nan")


# --------------------------------------------------------------------------- per take


def evaluate_take(pred_cam, gt_cam, gt_px, K, present, valid, pred_px=None, alignment_config=None, *,
                  anchor_depth=None, take: str = "", subject: str = "", obj: str | None = None,
                  dataset: str = "arctic", detector: str = "", detector_version: str = "",
                  note: str | None = None, anchor_depth_source: str | None = None) -> list[dict]:
    """One row per hand (left, then right) of the thesis's metrics for one take.

    Args:
        pred_cam: (T, 2, 21, 3) predicted camera-frame joints (m), slot 0 = left; NaN where absent.
        gt_cam: (T, 2, 21, 3) ground truth (m). gt_px: (T, 2, 21, 2) ground-truth 2D joints (px) or
            None (then the projection of gt_cam with K).
        K: (3, 3) or (T, 3, 3) (ARCTIC's egocentric camera has one per frame).
        present: (T, 2) the detector found the hand. valid: (T, 2) the ground truth is usable.
        pred_px: (T, 2, 21, 2) the detector's own 2D keypoints (optional): used by the alignment's
            swap repair and for the ``*_pred`` 2D metrics.
        alignment_config: None (demoforge.lib.ingest.alignment's defaults with surface_offset_m = 0, since the anchor
            depth is a joint-centre depth, and depth_outlier_m = None: the temporal depth-outlier
            check is meant for occluded depth readings, which ground truth has none of, and on
            the synthetic takes it rejects real hand motion of > 2 cm), "thesis" (AlignmentConfig.thesis(): anchor joint 2,
            translation only, hold-freeze) or an AlignmentConfig.
        anchor_depth: (T, 2, A) depth at the anchors in input slot order. Default: from the GROUND
            TRUTH -- the GT camera z of the anchor joints (the dataset has no depth camera; this is
            the thesis's "true 3D position" of the anchor). Give measured depths for RGB-D takes.

    Returns: list of 2 dicts (see the module doc for the metric keys).
    """
    P = np.asarray(pred_cam, np.float64)
    G = np.asarray(gt_cam, np.float64)
    T = G.shape[0]
    if P.shape != (T, 2, 21, 3) or G.shape != (T, 2, 21, 3):
        raise ValueError(f"pred_cam and gt_cam must be (T, 2, 21, 3), got {P.shape} and {G.shape}")
    present = np.asarray(present, bool) & np.isfinite(P).all(axis=(2, 3))
    valid = np.asarray(valid, bool) & np.isfinite(G).all(axis=(2, 3))
    if present.shape != (T, 2) or valid.shape != (T, 2):
        raise ValueError(f"present and valid must be ({T}, 2), got {present.shape} and {valid.shape}")
    K = np.asarray(K, np.float64)
    gpx = project_per_frame(G, K) if gt_px is None else np.asarray(gt_px, np.float64)
    ppx = None if pred_px is None else np.asarray(pred_px, np.float64)
    P = np.where(present[..., None, None], P, np.nan)

    # --- depth alignment (the ingest's) ---------------------------------------------------------
    cfg, cfg_name = _resolve_config(alignment_config)
    K0, ppx0 = common_K(K, None if ppx is None else np.where(present[..., None, None], ppx, np.nan))
    anchors = np.asarray(cfg.anchors)
    if anchor_depth is None:
        anchor_depth = gt_anchor_depth(P, G, K, anchors, pred_px=ppx, gt_px=gpx, valid=valid)
        src = "ground_truth" if anchor_depth_source is None else anchor_depth_source
        if note is None:
            note = GT_ANCHOR_NOTE
    else:
        src = "depth" if anchor_depth_source is None else anchor_depth_source
    res = align_to_depth(P, None, K0, joints_px=ppx0, config=cfg, anchor_depth=np.asarray(anchor_depth, np.float64))
    A = res.joints_aligned                     # physical hand order after swap repair
    det_al = res.detected
    A_all = res.joints_cam                     # incl. frozen / filled frames

    # --- 2D --------------------------------------------------------------------------------------
    p2 = project_per_frame(P, K)
    a2 = project_per_frame(A, K)

    rows = []
    for h, side in enumerate(SIDES):
        m = (valid[:, h] & present[:, h])[:, None]              # (T, 1) -> broadcast over joints
        ma = (valid[:, h] & det_al[:, h])[:, None]
        mall = (valid[:, h] & np.isfinite(A_all[:, h]).all(axis=(1, 2)))[:, None]
        n_valid = int(valid[:, h].sum())
        n_eval = int(m.sum())
        row: dict[str, Any] = {
            "dataset": dataset, "take": take, "subject": subject, "object": obj,
            "size_group": size_group(obj), "hand": side, "detector": detector,
            "detector_version": detector_version,
            "n_frames": int(T), "n_valid": n_valid, "n_detected": int(present[:, h].sum()),
            "n_eval": n_eval, "n_eval_aligned": int(ma.sum()),
            "detection_rate": n_eval / n_valid if n_valid else float("nan"),
            "mpjpe_m": mpjpe(P[:, h], G[:, h], m),
            "mpjpe_aligned_m": mpjpe(A[:, h], G[:, h], ma),
            "mpjpe_aligned_all_m": mpjpe(A_all[:, h], G[:, h], mall),
            "pa_mpjpe_m": pa_mpjpe(P[:, h], G[:, h], m),
            "pa_mpjpe_aligned_m": pa_mpjpe(A[:, h], G[:, h], ma),
            "rr_mpjpe_m": root_relative_mpjpe(P[:, h], G[:, h], m),
            "mpjpe_2d_px": mpjpe_2d(p2[:, h], gpx[:, h], m),
            "pck05": pck(p2[:, h], gpx[:, h], 0.05, m),
            "pck15": pck(p2[:, h], gpx[:, h], 0.15, m),
            "mpjpe_2d_aligned_px": mpjpe_2d(a2[:, h], gpx[:, h], ma),
            "pck05_aligned": pck(a2[:, h], gpx[:, h], 0.05, ma),
            "pck15_aligned": pck(a2[:, h], gpx[:, h], 0.15, ma),
            "mpjpe_2d_pred_px": mpjpe_2d(ppx[:, h], gpx[:, h], m) if ppx is not None else float("nan"),
            "pck05_pred": pck(ppx[:, h], gpx[:, h], 0.05, m) if ppx is not None else float("nan"),
            "pck15_pred": pck(ppx[:, h], gpx[:, h], 0.15, m) if ppx is not None else float("nan"),
            "n_swap_repaired": int(res.swap_repaired[:, h].sum()),
            "n_outlier_frozen": int(res.outlier_frozen[:, h].sum()),
            "alignment": cfg_name, "anchor_depth_source": src, "note": note or "",
        }
        rows.append(row)
    return rows


def evaluate_arctic_take(take, pred_cam, present=None, pred_px=None, alignment_config=None, *,
                         detector: str = "", detector_version: str = "") -> list[dict]:
    """:func:`evaluate_take` for a demoforge.lib.evaluation.arctic.ArcticTake (or a HandTrack as ``pred_cam``)."""
    if hasattr(pred_cam, "joints_cam"):            # a HandTrack
        track = pred_cam
        pred_cam, present = track.joints_cam, track.present if present is None else present
        pred_px = track.joints_px if pred_px is None else pred_px
        detector = detector or track.detector
        detector_version = detector_version or track.detector_version
    if present is None:
        present = np.isfinite(np.asarray(pred_cam)).all(axis=(2, 3))
    return evaluate_take(pred_cam, take.joints_cam, take.joints_px, take.K, present, take.valid, pred_px,
                         alignment_config, take=take.seq, subject=take.subject, obj=take.object,
                         dataset="arctic", detector=detector, detector_version=detector_version)


def load_synth_ground_truth(take_dir: Path, T: int):
    import pyarrow.parquet as pq

    path = take_dir / "ground_truth" / "gt_hand_joints.parquet"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: not a synthetic take (demoforge.lib.synth.take.generate_take)")
    tbl = pq.read_table(path, columns=["frame", "hand", "joints_camera", "joints_px", "present"])
    frame = np.asarray(tbl["frame"].to_numpy(), np.int64)
    hand = np.asarray(tbl["hand"].to_pylist())
    h = np.where(hand == "left", 0, 1)
    cam = np.asarray(tbl["joints_camera"].to_pylist(), float).reshape(-1, 21, 3)
    px = np.asarray(tbl["joints_px"].to_pylist(), float).reshape(-1, 21, 2)
    px = np.where(np.abs(px) >= 1e5, np.nan, px)            # the writer's NaN sentinel (+-1e6)
    pres = np.asarray(tbl["present"].to_numpy(zero_copy_only=False), bool)
    gt = np.full((T, 2, 21, 3), np.nan)
    gpx = np.full((T, 2, 21, 2), np.nan)
    valid = np.zeros((T, 2), bool)
    k = frame < T
    gt[frame[k], h[k]] = cam[k]
    gpx[frame[k], h[k]] = px[k]
    valid[frame[k], h[k]] = pres[k]
    valid &= np.isfinite(gt).all(axis=(2, 3)) & (gt[..., 2] > 0).all(-1) & np.isfinite(gpx).all(axis=(2, 3))
    return gt, gpx, valid


def evaluate_synthetic_take(take_path: str | os.PathLike, detector: str = "simulated", alignment_config=None,
                            anchor_depth_source: str = "depth", depth_batch: int = 32, **detector_kw) -> list[dict]:
    """Rows of :func:`evaluate_take` for a synthetic take (demoforge.lib.synth.take layout) and a detector
    (default the simulated HaMeR: ``get_detector("simulated").detect_take(open_take(path))``).

    Ground truth: ground_truth/gt_hand_joints.parquet (joints_camera, joints_px, present).
    ``anchor_depth_source``: "depth" (default: the take's rendered depth maps, read in batches
    at the prediction's 2D anchors like the ingest does) or "ground_truth" (as for ARCTIC).
    """
    take = open_take(take_path)
    det = get_detector(detector, **detector_kw)
    track = det.detect_take(take)
    T = track.n_frames
    gt, gpx, valid = load_synth_ground_truth(Path(take.path), T)
    cfg, _ = _resolve_config(alignment_config)
    anchor_depth = None
    note = None
    if anchor_depth_source == "depth":
        if alignment_config is None:
            cfg = AlignmentConfig()      # measured depth sees the skin: keep the default surface offset
            alignment_config = cfg
        anchors = np.asarray(cfg.anchors)
        uv = np.where(track.present[..., None, None], track.joints_px, np.nan)[:, :, anchors, :]
        anchor_depth = np.full(uv.shape[:-1], np.nan)
        for idx, depth in iter_depth(take, depth_batch):
            z, _ = read_depth_robust(depth, uv[idx], cfg.window, cfg.min_valid)
            anchor_depth[idx] = z
        note = "aligned metrics: anchor depth read from the take's depth maps"
    elif anchor_depth_source != "ground_truth":
        raise ValueError(f"anchor_depth_source must be 'depth' or 'ground_truth', got {anchor_depth_source!r}")
    task = str(take.meta.get("task", "")) or None
    return evaluate_take(track.joints_cam, gt, gpx, take.K, track.present, valid, track.joints_px,
                         alignment_config, anchor_depth=anchor_depth, take=take.take_id, obj=task,
                         dataset="synthetic", detector=track.detector, detector_version=track.detector_version,
                         note=note)


# --------------------------------------------------------------------------- real photos


def real_photo_rows(results, detector: str = "mediapipe", alphas: Sequence[float] = (0.05, 0.15, 0.2)) -> list[dict]:
    """Rows from demoforge.lib.evaluation.real_photos.evaluate's DatasetResults, one per dataset plus "all":
    detection rate, handedness accuracy, 2D MPJPE (px) and PCK@alpha normalised by the labelled box
    size, over the detected hands (``pckXX``) and over all labelled joints (``pckXX_all``: joints of
    missed hands count as wrong)."""
    out = []
    res = list(results)

    def row(name, images, hands, detected, side_known, side_correct, errors, norm_errors, joints_all):
        e = np.concatenate(errors) if errors else np.zeros(0)
        ne = np.concatenate(norm_errors) if norm_errors else np.zeros(0)
        r = {"dataset": name, "detector": detector, "images": images, "hands": hands, "detected": detected,
             "detection_rate": detected / hands if hands else float("nan"),
             "handedness_known": side_known,
             "handedness_acc": side_correct / side_known if side_known else float("nan"),
             "mpjpe_2d_px": float(e.mean()) if e.size else float("nan")}
        for a in alphas:
            k = f"pck{round(a * 100):02d}"
            hit = int((ne < a).sum())
            r[k] = hit / ne.size if ne.size else float("nan")
            r[k + "_all"] = hit / joints_all if joints_all else float("nan")
        return r

    for r in res:
        out.append(row(r.dataset, r.images, r.hands, r.detected, r.side_known, r.side_correct,
                       r.errors, r.norm_errors, r.joints_all))
    if res:
        out.append(row("all", sum(r.images for r in res), sum(r.hands for r in res),
                       sum(r.detected for r in res), sum(r.side_known for r in res),
                       sum(r.side_correct for r in res), [e for r in res for e in r.errors],
                       [e for r in res for e in r.norm_errors], sum(r.joints_all for r in res)))
    return out


def evaluate_real_photos(detector=None, data_dir: str | os.PathLike | None = None, **kw) -> list[dict]:
    """Run demoforge.lib.evaluation.real_photos.evaluate (default: MediaPipe on shared/data/real_hands)
    and return :func:`real_photo_rows`."""

    data = Path(data_dir) if data_dir is not None else SHARED_DATA / "real_hands"
    if detector is None:
        with MediaPipeDetector() as det:
            return real_photo_rows(rpe.evaluate(det, data, **kw), detector="mediapipe")
    return real_photo_rows(rpe.evaluate(detector, data, **kw), detector=getattr(detector, "name", str(detector)))


# --------------------------------------------------------------------------- tables


def _avg(rows: Sequence[dict], key: str, weighting: str, weight_key: str = "n_eval") -> float:
    vals, ws = [], []
    for r in rows:
        v = r.get(key)
        if v is None or not np.isfinite(v):
            continue
        w = 1.0 if weighting == "takes" else float(r.get(weight_key) or 0)
        if w > 0:
            vals.append(float(v))
            ws.append(w)
    if weighting not in ("takes", "frames"):
        raise ValueError(f"weighting must be 'frames' or 'takes', got {weighting!r}")
    return float(np.average(vals, weights=ws)) if vals else float("nan")


def _take_order(rows: Sequence[dict]) -> list[str]:
    takes = list(dict.fromkeys(r.get("take", "") for r in rows))
    rank = {t: i for i, t in enumerate(APPENDIX_B_ORDER)}
    return sorted(takes, key=lambda t: (rank.get(t, len(rank)), takes.index(t)))


GROUP_METRICS = ("mpjpe_aligned_m", "pa_mpjpe_m", "mpjpe_m", "mpjpe_2d_px", "mpjpe_2d_aligned_px", "pck05", "pck15")


def _group(rows, key_fn, groups, weighting, metrics=GROUP_METRICS):
    out = []
    for g in groups:
        rs = [r for r in rows if key_fn(r) == g]
        if not rs:
            continue
        d = {"n_takes": len({r.get("take") for r in rs}), "n_rows": len(rs)}
        for m in metrics:
            wk = "n_eval_aligned" if "aligned" in m else "n_eval"
            d[m] = _avg(rs, m, weighting, wk)
        out.append((g, d))
    return out


def per_object(rows: Sequence[dict], weighting: str = "frames") -> list[dict]:
    """Figures 19-20: per object, metrics averaged over the left and right hands and the takes."""
    objs = list(dict.fromkeys([o for o in OBJECT_LABELS] + [r.get("object") for r in rows]))
    return [{"object": g, "label": OBJECT_LABELS.get(g, str(g)), "size_group": size_group(g), **d}
            for g, d in _group(rows, lambda r: r.get("object"), objs, weighting)]


def big_vs_small(rows: Sequence[dict], weighting: str = "frames") -> list[dict]:
    """Figure 21: the thesis's grouping (big = box, capsule machine, espresso machine; small =
    ketchup, phone, scissors), metrics averaged over hands and takes within each group."""
    return [{"group": g, "objects": ", ".join(BIG_OBJECTS if g == "big" else SMALL_OBJECTS), **d}
            for g, d in _group(rows, lambda r: size_group(r.get("object")), ("big", "small"), weighting)]


# --------------------------------------------------------------------------- figures

_LABELS = {"mpjpe_m": "MPJPE (m)", "mpjpe_aligned_m": "MPJPE aligned (m)", "pa_mpjpe_m": "PA-MPJPE (m)",
           "pa_mpjpe_aligned_m": "PA-MPJPE aligned (m)", "rr_mpjpe_m": "root-relative MPJPE (m)",
           "mpjpe_2d_px": "2D MPJPE (px)", "mpjpe_2d_aligned_px": "2D MPJPE after alignment (px)",
           "pck05": "PCK@0.05", "pck15": "PCK@0.15", "detection_rate": "detection rate"}


def _bars(groups: list[str], series: dict[str, list[float]], ylabel: str, title: str, out_png) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    n = max(len(series), 1)
    x = np.arange(len(groups))
    w = 0.8 / n
    fig, ax = plt.subplots(figsize=(max(5.0, 0.55 * len(groups) * n + 2), 4.0))
    for i, (name, vals) in enumerate(series.items()):
        v = np.asarray(vals, float)
        bars = ax.bar(x + (i - (n - 1) / 2) * w, np.nan_to_num(v), w, label=name)
        for b, val in zip(bars, v):
            if np.isfinite(val):
                ax.annotate(f"{val:.3g}", (b.get_x() + b.get_width() / 2, b.get_height()),
                            ha="center", va="bottom", fontsize=6)
    ax.set_xticks(x)
    ax.set_xticklabels(groups, rotation=45 if len(groups) > 6 else 0, ha="right" if len(groups) > 6 else "center",
                       fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_per_take_bars(rows: Sequence[dict], metric: str, out_png) -> Path:
    """Grouped bars per take (left / right hand) of one metric (Appendix B as a chart)."""
    takes = _take_order(rows)
    series = {}
    for side in SIDES:
        d = {r.get("take"): r.get(metric, float("nan")) for r in rows if r.get("hand") == side}
        series[side] = [d.get(t, float("nan")) for t in takes]
    return _bars(takes, series, _LABELS.get(metric, metric), f"{_LABELS.get(metric, metric)} per take", out_png)


def plot_per_object_bars(rows: Sequence[dict], metrics: Sequence[str], out_png, weighting: str = "frames") -> Path:
    """Figures 19 (metrics = mpjpe_aligned_m, pa_mpjpe_m) and 20 (pck05, pck15 / mpjpe_2d_aligned_px):
    per object, averaged over both hands."""
    po = per_object(rows, weighting)
    labels = [p["label"] for p in po]
    series = {_LABELS.get(m, m): [p.get(m, float("nan")) for p in po] for m in metrics}
    ylabel = " / ".join(_LABELS.get(m, m) for m in metrics)
    return _bars(labels, series, ylabel, "per object (mean of left and right hands)", out_png)


def plot_big_vs_small(rows: Sequence[dict], out_png, kind: str = "3d", weighting: str = "frames") -> Path:
    """Figure 21: (a) kind="3d": MPJPE aligned and PA-MPJPE; (b) kind="2d": PCK@0.05 and PCK@0.15,
    big vs small objects."""
    metrics = {"3d": ("mpjpe_aligned_m", "pa_mpjpe_m"), "2d": ("pck05", "pck15")}[kind]
    bs = big_vs_small(rows, weighting)
    series = {_LABELS[m]: [g.get(m, float("nan")) for g in bs] for m in metrics}
    title = ("Big vs Small Object Comparison 3D (lower is better)" if kind == "3d"
             else "Big vs Small Object Comparison 2D (higher is better)")
    return _bars([g["group"] for g in bs], series, "m" if kind == "3d" else "fraction", title, out_png)


def format_markdown(rows: Sequence[dict], columns: Sequence[str] | None = None, digits: int = 3) -> str:
    """A Markdown table of dict rows (floats to ``digits`` decimals)."""
    rows = list(rows)
    cols = list(columns) if columns else (list(rows[0].keys()) if rows else [])

    def fmt(v):
        if isinstance(v, float):
            return "nan" if math.isnan(v) else f"{v:.{digits}f}"
        return "" if v is None else str(v)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(lines)
