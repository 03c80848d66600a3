"""Evaluate a hand detector on the labelled real hand photos (shared/data/real_hands, mmpose test data).

Each labelled hand (COCO-style ``keypoints`` 21 x (u, v, visibility); COCO-WholeBody's
``lefthand_kpts`` / ``righthand_kpts`` per person) is matched to the detected hand whose 2D keypoints
are nearest (mean distance over the labelled joints); it counts as detected when that distance is
below ``match_factor`` x the box size. Box size = max(w, h) of the labelled bbox (COCO-WholeBody:
``lefthand_box`` / ``righthand_box``). Only joints with visibility > 0 count.

Metrics per dataset: images, hands labelled, hands detected, handedness accuracy (over detected hands
with a known side: COCO-WholeBody left/right keys, Panoptic ``_l`` / ``_r`` files, FreiHAND = right
hands only), 2D MPJPE (px) and PCK@0.2 over the detected hands, and PCK@0.2 over all labelled hands
(joints of missed hands count as wrong).

    .venv/bin/python -m demoforge.lib.evaluation.real_photos [DATA_DIR]
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from demoforge.lib import SHARED_DATA
from demoforge.lib.perception.detectors.mediapipe_backend import MediaPipeDetector

DATASETS = ("freihand", "onehand10k", "panoptic", "coco_wholebody")


@dataclass
class LabelledHand:
    image: str
    kpts: np.ndarray          # (21, 2)
    vis: np.ndarray           # (21,) bool
    box_size: float
    side: str | None          # "left" | "right" | None (unknown)


@dataclass
class DatasetResult:
    dataset: str
    images: int = 0
    hands: int = 0
    detected: int = 0
    side_known: int = 0
    side_correct: int = 0
    raw_label_equals_side: int = 0
    errors: list = field(default_factory=list)      # per labelled joint of detected hands, px
    norm_errors: list = field(default_factory=list)  # per labelled joint / box size, detected hands
    joints_all: int = 0                              # labelled joints incl. missed hands
    seconds: float = 0.0

    def row(self) -> dict:
        e = np.concatenate(self.errors) if self.errors else np.zeros(0)
        ne = np.concatenate(self.norm_errors) if self.norm_errors else np.zeros(0)
        ok = int((ne < 0.2).sum())
        return {
            "dataset": self.dataset, "images": self.images, "hands": self.hands, "detected": self.detected,
            "detection_rate": self.detected / self.hands if self.hands else float("nan"),
            "handedness_known": self.side_known,
            "handedness_acc": self.side_correct / self.side_known if self.side_known else float("nan"),
            "raw_label_is_person_hand": (self.raw_label_equals_side / self.side_known
                                         if self.side_known else float("nan")),
            "mpjpe_px": float(e.mean()) if e.size else float("nan"),
            "pck02_detected": ok / ne.size if ne.size else float("nan"),
            "pck02_all": ok / self.joints_all if self.joints_all else float("nan"),
            "ms_per_image": 1000 * self.seconds / self.images if self.images else float("nan"),
        }


def _hand(image: str, kp: list, box: list, side: str | None) -> LabelledHand | None:
    a = np.asarray(kp, float).reshape(21, 3)
    vis = a[:, 2] > 0
    if vis.sum() == 0:
        return None
    size = float(max(box[2], box[3])) if box is not None and max(box[2], box[3]) > 0 else float(
        np.ptp(a[vis, :2], axis=0).max())
    return LabelledHand(image, a[:, :2], vis, size, side)


def load_labels(data_dir: Path, dataset: str) -> dict[str, list[LabelledHand]]:
    """{image file name: labelled hands} of one dataset folder."""
    folder = data_dir / dataset
    j = json.loads(next(folder.glob("*.json")).read_text())
    names = {im["id"]: im["file_name"] for im in j["images"]}
    out: dict[str, list[LabelledHand]] = {n: [] for n in names.values()}
    for a in j["annotations"]:
        img = names[a["image_id"]]
        if dataset == "coco_wholebody":
            for side in ("left", "right"):
                if a.get(f"{side}hand_valid") and a.get(f"{side}hand_kpts"):
                    h = _hand(img, a[f"{side}hand_kpts"], a.get(f"{side}hand_box"), side)
                    if h is not None:
                        out[img].append(h)
        else:
            side = None
            if dataset == "panoptic":
                stem = Path(img).stem
                side = "left" if stem.endswith("_l") else ("right" if stem.endswith("_r") else None)
            elif dataset == "freihand":
                side = "right"          # FreiHAND shows right hands only
            h = _hand(img, a["keypoints"], a.get("bbox"), side)
            if h is not None:
                out[img].append(h)
    return out


def evaluate(detector, data_dir: Path, datasets=DATASETS, match_factor: float = 1.0) -> list[DatasetResult]:
    """Run ``detector.detect_image(rgb)`` on every labelled image; metrics per dataset."""
    import cv2

    results = []
    for ds in datasets:
        r = DatasetResult(ds)
        for img_name, hands in load_labels(data_dir, ds).items():
            bgr = cv2.imread(str(data_dir / ds / img_name), cv2.IMREAD_COLOR)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            t0 = time.perf_counter()
            cands = detector.detect_image(rgb)
            r.seconds += time.perf_counter() - t0
            r.images += 1
            for h in hands:
                r.hands += 1
                r.joints_all += int(h.vis.sum())
                best, best_d = None, np.inf
                for c in cands:
                    d = np.linalg.norm(c.joints_px[h.vis] - h.kpts[h.vis], axis=1).mean()
                    if d < best_d:
                        best, best_d = c, d
                if best is None or best_d > match_factor * h.box_size:
                    continue
                r.detected += 1
                err = np.linalg.norm(best.joints_px[h.vis] - h.kpts[h.vis], axis=1)
                r.errors.append(err)
                r.norm_errors.append(err / h.box_size)
                if h.side is not None:
                    r.side_known += 1
                    r.side_correct += int(best.handedness == h.side)
                    r.raw_label_equals_side += int(best.extra.get("raw_label", "").lower() == h.side)
        results.append(r)
    return results


def handedness_on_crops(detector, data_dir: Path, datasets=("coco_wholebody", "panoptic"),
                        context: float = 3.0, size: int = 256) -> tuple[int, int, int]:
    """Handedness check on crops around each labelled hand (context x box size, resized to ``size``):
    the hands of COCO-WholeBody are too small (11-30 px) for the full-image palm detector, but a crop
    keeps the hand's chirality. Returns (hands with a detection in the crop, correct side, raw label
    == person's hand); the detection nearest to the crop centre is used."""
    import cv2

    n = correct = raw = 0
    for ds in datasets:
        for img_name, hands in load_labels(data_dir, ds).items():
            bgr = cv2.imread(str(data_dir / ds / img_name), cv2.IMREAD_COLOR)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            H, W = rgb.shape[:2]
            for h in hands:
                if h.side is None:
                    continue
                c = h.kpts[h.vis].mean(axis=0)
                half = 0.5 * context * h.box_size
                x0, y0 = int(max(0, c[0] - half)), int(max(0, c[1] - half))
                x1, y1 = int(min(W, c[0] + half)), int(min(H, c[1] + half))
                if x1 - x0 < 4 or y1 - y0 < 4:
                    continue
                crop = cv2.resize(rgb[y0:y1, x0:x1], (size, size), interpolation=cv2.INTER_CUBIC)
                cands = detector.detect_image(crop)
                if not cands:
                    continue
                ctr = np.array([size / 2, size / 2])
                best = min(cands, key=lambda k: np.linalg.norm(k.joints_px.mean(0) - ctr))
                n += 1
                correct += int(best.handedness == h.side)
                raw += int(best.extra.get("raw_label", "").lower() == h.side)
    return n, correct, raw


def format_table(results: list[DatasetResult]) -> str:
    cols = ["dataset", "images", "hands", "detected", "handedness_known", "handedness_acc", "mpjpe_px",
            "pck02_detected", "pck02_all", "ms_per_image"]
    rows = [r.row() for r in results]
    tot = DatasetResult("all")
    for r in results:
        for k in ("images", "hands", "detected", "side_known", "side_correct", "raw_label_equals_side",
                  "joints_all", "seconds"):
            setattr(tot, k, getattr(tot, k) + getattr(r, k))
        tot.errors += r.errors
        tot.norm_errors += r.norm_errors
    rows.append(tot.row())
    fmt = lambda v: f"{v:.3f}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r[c]) for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv

    data = Path(args[0]) if args else SHARED_DATA / "real_hands"
    with MediaPipeDetector() as det:
        res = evaluate(det, data)
    print(format_table(res))
    for r in res:
        row = r.row()
        print(f"{r.dataset}: raw MediaPipe label == person's hand on {row['raw_label_is_person_hand']}")
    with MediaPipeDetector() as det:
        n, ok, raw = handedness_on_crops(det, data)
    print(f"handedness on crops around labelled hands (coco_wholebody + panoptic): {ok}/{n} correct, "
          f"raw label == person's hand {raw}/{n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
