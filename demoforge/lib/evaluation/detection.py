"""Hand DETECTION measured against a synthetic take's ground truth (2D, per frame, before tracking).

For every frame the detector's raw candidates (:meth:`demoforge.lib.perception.detectors.HandDetector.detect`, no
selection, no filling) are matched to the ground-truth hands, and each hand-frame counts where
the hand is worth detecting: at least ``min_visible`` (default 80 %) of its 21 joints project into
the image ("in view"). ``gt_hand_joints.visible`` -- additionally not hidden behind any surface, by
the exact rendered depth -- is not the criterion: from a camera above the table about half of a
hand's joints are behind its own back or palm, which a detector infers as a matter of course, and
hardly any hand-frame of the default takes has 80 % of its joints visible in that sense.

Matching: a candidate and a ground-truth hand are a pair when the mean pixel distance of the
candidate's 21 2D keypoints to the hand's in-view ground-truth joints is below ``match_factor``
times the hand's box size (the larger side of the tight box of its 21 ground-truth 2D joints);
pairs are assigned by increasing distance, one candidate per hand. The side label is ignored when
matching, so handedness is measured separately.

Per row (take x subset): ``hand_frames`` eligible, ``detected`` (matched), ``detection_rate``,
``handedness_acc`` over the matched ones (candidate's ``handedness`` equals the hand's side),
``mpjpe_2d_px`` (mean over the in-view joints of matched hands), ``pck05``/``pck15`` (fraction of
those joints within 0.05/0.15 of the box size: the normalisation of the real-photos evaluation,
demoforge.lib.evaluation.keypoints.real_photo_rows, there the labelled box) and ``spurious_per_frame``
(unmatched candidates per frame). Subsets: ``all`` and ``occluded`` -- hand-frames where the hand
holds an object (``gt_gripper.held_object``) and at least one of its in-view joints is hidden
by the depth test (the held object, the other hand, or its own palm covers part of it).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from demoforge.lib.perception.detectors import get_detector
from demoforge.lib.takes import open_take
from demoforge.lib.takes.reader import iter_frames

SIDES = ("left", "right")
SUBSETS = ("all", "occluded")


def load_ground_truth(take_dir: str | os.PathLike) -> dict[str, np.ndarray]:
    """{"px": (T, 2, 21, 2) (NaN where not projectable), "in_view": (T, 2, 21) (projects into the
    image), "visible": (T, 2, 21) (in view and not hidden), "holding": (T, 2)} from a take's
    ground_truth/ tables and camera.json."""
    import json

    import pyarrow.parquet as pq

    gt_dir = Path(take_dir) / "ground_truth"
    hj_path = gt_dir / "gt_hand_joints.parquet"
    if not hj_path.is_file():
        raise FileNotFoundError(f"{hj_path} does not exist: detection is measured on synthetic takes only")
    hj = pq.read_table(hj_path, columns=["frame", "hand", "joints_px", "visible"])
    frame = np.asarray(hj["frame"].to_numpy(), np.int64)
    h = np.where(np.asarray(hj["hand"].to_pylist()) == "left", 0, 1)
    T = int(frame.max()) + 1
    px = np.full((T, 2, 21, 2), np.nan)
    vis = np.zeros((T, 2, 21), bool)
    raw = np.asarray(hj["joints_px"].to_pylist(), float).reshape(-1, 21, 2)
    px[frame, h] = np.where(np.abs(raw) >= 1e5, np.nan, raw)       # the writer's +-1e6 sentinel
    vis[frame, h] = np.asarray(hj["visible"].to_pylist(), bool).reshape(-1, 21)
    gr = pq.read_table(gt_dir / "gt_gripper.parquet", columns=["frame", "hand", "held_object"])
    gf = np.asarray(gr["frame"].to_numpy(), np.int64)
    gh = np.where(np.asarray(gr["hand"].to_pylist()) == "left", 0, 1)
    holding = np.zeros((T, 2), bool)
    holding[gf, gh] = [o is not None and o != "" for o in gr["held_object"].to_pylist()]
    cam = json.loads((Path(take_dir) / "camera.json").read_text())
    W, H = int(cam["width"]), int(cam["height"])
    with np.errstate(invalid="ignore"):
        in_view = (np.isfinite(px).all(-1) & (px[..., 0] >= -0.5) & (px[..., 0] < W - 0.5)
                   & (px[..., 1] >= -0.5) & (px[..., 1] < H - 0.5))
    return {"px": px, "in_view": in_view, "visible": vis & in_view, "holding": holding}


def box_size(px: np.ndarray) -> np.ndarray:
    """(...,) larger side of the tight box of (..., 21, 2) points (NaN points ignored)."""
    with np.errstate(invalid="ignore"):
        ext = np.nanmax(px, axis=-2) - np.nanmin(px, axis=-2)
    return np.nanmax(ext, axis=-1)


def match_frame(cands_px: np.ndarray, gt_px: np.ndarray, gt_vis: np.ndarray, size: np.ndarray,
                match_factor: float = 0.5) -> np.ndarray:
    """Candidate index matched to each of the hands (H,) (-1 = none).

    cands_px (C, 21, 2); gt_px (H, 21, 2); gt_vis (H, 21); size (H,). Greedy by increasing mean
    distance over the joints with ``gt_vis`` set (the in-view ones), gated at ``match_factor * size``.
    """
    H = gt_px.shape[0]
    out = np.full(H, -1)
    if len(cands_px) == 0:
        return out
    d = np.linalg.norm(cands_px[:, None] - gt_px[None], axis=-1)           # (C, H, 21)
    w = gt_vis[None].astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = np.nansum(np.where(w > 0, d, 0.0), -1) / w.sum(-1)           # (C, H)
    cost = np.where(np.isfinite(cost) & (cost < match_factor * size[None]), cost, np.inf)
    used = set()
    for flat in np.argsort(cost, axis=None):
        c, h = np.unravel_index(flat, cost.shape)
        if not np.isfinite(cost[c, h]):
            break
        if out[h] < 0 and c not in used:
            out[h] = c
            used.add(int(c))
    return out


def score_take(candidates: Sequence[Sequence[Any]], gt: dict[str, np.ndarray], min_visible: float = 0.8,
               match_factor: float = 0.5, alphas: Sequence[float] = (0.05, 0.15)) -> list[dict]:
    """Rows (one per subset) from per-frame candidate lists (objects with ``joints_px`` (21, 2) and
    ``handedness``) and :func:`load_ground_truth`'s arrays (frames beyond either are ignored)."""
    px, view, holding = gt["px"], gt["in_view"], gt["holding"]
    T = min(len(candidates), len(px))
    size = box_size(px[:T])                                                   # (T, 2)
    vis = view[:T]
    eligible = vis.mean(-1) >= min_visible                                    # (T, 2)
    occluded = eligible & holding[:T] & (vis & ~gt["visible"][:T]).any(-1)
    matched = np.zeros((T, 2), bool)
    side_ok = np.zeros((T, 2), bool)
    err = np.full((T, 2, 21), np.nan)
    spurious = np.zeros(T, int)
    for t in range(T):
        cands = list(candidates[t])
        cpx = np.array([np.asarray(c.joints_px, float) for c in cands]).reshape(-1, 21, 2)
        m = match_frame(cpx, px[t], vis[t], size[t], match_factor)
        spurious[t] = len(cands) - int((m >= 0).sum())
        for h in range(2):
            if m[h] >= 0:
                matched[t, h] = True
                side_ok[t, h] = cands[m[h]].handedness == SIDES[h]
                e = np.linalg.norm(cpx[m[h]] - px[t, h], axis=-1)
                err[t, h] = np.where(vis[t, h], e, np.nan)
    rows = []
    for subset, mask in (("all", eligible), ("occluded", occluded)):
        n = int(mask.sum())
        det = mask & matched
        nd = int(det.sum())
        e = err[det]                                          # (nd, 21), NaN = joint out of view
        ne = e / size[det][:, None]
        ev, nev = e[np.isfinite(e)], ne[np.isfinite(ne)]
        row = {"subset": subset, "hand_frames": n, "detected": nd,
               "detection_rate": nd / n if n else float("nan"),
               "handedness_acc": float(side_ok[det].mean()) if nd else float("nan"),
               "mpjpe_2d_px": float(ev.mean()) if ev.size else float("nan"),
               "spurious_per_frame": float(spurious.mean()) if T else float("nan"),
               "frames": int(T)}
        for a in alphas:
            row[f"pck{round(a * 100):02d}"] = float((nev < a).mean()) if nev.size else float("nan")
        rows.append(row)
    return rows


def detect_candidates(take_dir: str | os.PathLike, detector: Any, batch_size: int = 16,
                      progress: Callable[[int, int], None] | None = None) -> tuple[list[list[Any]], float]:
    """Raw candidates per frame of a take (frames in order; a detector with ``start_take`` -- MediaPipe
    -- is told a take starts, so its video mode tracks) and the seconds the detector itself took."""
    take = open_take(take_dir)
    per_frame: list[list[Any]] = [[] for _ in range(take.n_frames)]
    seconds = 0.0
    done = 0
    if hasattr(detector, "start_take"):
        detector.start_take()
    for batch in iter_frames(take, batch_size=batch_size):
        t0 = time.perf_counter()
        out = detector.detect(batch.rgb, take.camera.K, batch.indices)
        seconds += time.perf_counter() - t0
        for i, c in zip(batch.indices.tolist(), out):
            per_frame[i] = list(c)
        done += len(batch.indices)
        if progress is not None:
            progress(done, take.n_frames)
    if hasattr(detector, "end_take"):
        detector.end_take()
    return per_frame, seconds


def evaluate_detection(take_dir: str | os.PathLike, detector: str = "mediapipe", min_visible: float = 0.8,
                       match_factor: float = 0.5, progress: Callable[[int, int], None] | None = None,
                       **detector_options: Any) -> list[dict]:
    """Rows of ``detection_metrics`` for one synthetic take and one detector (a fresh detector per
    take, so a video-mode tracker starts clean)."""
    import json

    take_dir = Path(take_dir)
    meta = json.loads((take_dir / "take.json").read_text())
    gt = load_ground_truth(take_dir)
    with get_detector(detector, **detector_options) as det:
        cands, seconds = detect_candidates(take_dir, det, progress=progress)
        version = getattr(det, "version", "")
        mode = getattr(det, "running_mode", "")
        mode = "video" if mode == "auto" else mode       # "auto" tracks takes in video mode
    rows = score_take(cands, gt, min_visible, match_factor)
    for r in rows:
        r.update({"take": meta.get("take", take_dir.name), "task": meta.get("task", ""),
                  "hand_style": meta.get("hand_style", "capsule"), "detector": detector,
                  "detector_version": version, "running_mode": mode or "",
                  "detect_seconds": seconds, "detect_fps": len(cands) / seconds if seconds > 0 else float("nan")})
    return rows


def per_task(rows: Iterable[dict]) -> list[dict]:
    """Pool take rows per (task, hand_style, detector, running_mode, subset): counts summed, rates
    re-derived, px/PCK weighted by detected hand-frames."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (r["task"], r.get("hand_style", ""), r["detector"], r.get("running_mode", ""), r["subset"])
        groups.setdefault(key, []).append(r)
    out = []
    for (task, style, det, mode, subset), rs in sorted(groups.items()):
        n = sum(r["hand_frames"] for r in rs)
        nd = sum(r["detected"] for r in rs)

        def wavg(k):
            w = [(r["detected"], r[k]) for r in rs if r["detected"] and np.isfinite(r[k])]
            tot = sum(a for a, _ in w)
            return sum(a * v for a, v in w) / tot if tot else float("nan")

        out.append({"task": task, "hand_style": style, "detector": det, "running_mode": mode, "subset": subset,
                    "takes": len(rs), "hand_frames": n, "detected": nd,
                    "detection_rate": nd / n if n else float("nan"),
                    "handedness_acc": wavg("handedness_acc"), "mpjpe_2d_px": wavg("mpjpe_2d_px"),
                    "pck05": wavg("pck05"), "pck15": wavg("pck15"),
                    "spurious_per_frame": float(np.mean([r["spurious_per_frame"] for r in rs]))})
    return out


def format_markdown(rows: Sequence[dict]) -> str:
    """A Markdown table of :func:`per_task` rows."""
    head = ("| task | look | mode | subset | hand-frames | detection | handedness | 2D MPJPE (px) | PCK@0.05 | "
            "PCK@0.15 | spurious / frame |\n|---|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        lines.append(f"| {r['task']} | {r['hand_style']} | {r['running_mode']} | {r['subset']} | {r['hand_frames']} | "
                     f"{r['detection_rate']:.3f} | {r['handedness_acc']:.3f} | {r['mpjpe_2d_px']:.1f} | "
                     f"{r['pck05']:.3f} | {r['pck15']:.3f} | {r['spurious_per_frame']:.3f} |")
    return "\n".join(lines)


__all__ = ["format_markdown", "SIDES", "SUBSETS", "load_ground_truth", "box_size", "match_frame", "score_take",
           "detect_candidates", "evaluate_detection", "per_task"]
