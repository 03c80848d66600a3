"""Table of hand detection measured against synthetic ground truth (lib/evaluation/detection.py)."""

import pyarrow as pa

from demoforge.schemas.core import Column, metric_column as _m, table


DETECTION_METRICS = table(
    "detection_metrics",
    version=1,
    doc=("A real detector's raw per-frame candidates (no tracking, no filling) against a synthetic take's "
         "ground truth, per take and subset. Hand-frames count when >= 80 % of the hand's 21 joints project "
         "into the image; a candidate matches a hand when its keypoints lie, on average, within half the "
         "hand's box size (larger side of the tight box of its ground-truth 2D joints). NaN when none."),
    columns=[
        Column("take", pa.string(), "Synthetic take, e.g. `synth_pouring_s0000`."),
        Column("task", pa.string(), "Task of the take."),
        Column("hand_style", pa.string(), "Look of the rendered hands: `skin` or `capsule`."),
        Column("detector", pa.string(), "Detector backend, e.g. `mediapipe`."),
        Column("detector_version", pa.string(), "Backend version (model file)."),
        Column("running_mode", pa.string(), "`video` (tracking between palm detections) or `image` (every frame alone)."),
        Column("subset", pa.string(), "`all` eligible hand-frames, or `occluded`: the hand holds an object and some of its in-view joints are hidden."),
        Column("frames", pa.int32(), "Frames of the take."),
        Column("hand_frames", pa.int32(), "Eligible hand-frames (frames x hands) in the subset."),
        Column("detected", pa.int32(), "Of those, matched by a candidate."),
        _m("detection_rate", "detected / hand_frames."),
        _m("handedness_acc", "Fraction of detected hand-frames whose candidate names the right side."),
        _m("mpjpe_2d_px", "Mean 2D distance of the matched candidates' keypoints to the in-view ground-truth joints, px."),
        _m("pck05", "Fraction of those joints within 0.05 x the hand's box size."),
        _m("pck15", "Fraction within 0.15 x the box size."),
        _m("spurious_per_frame", "Candidates matched to no hand, per frame (whole take)."),
        _m("detect_seconds", "Wall time of the detector over the take, s."),
        _m("detect_fps", "frames / detect_seconds."),
    ],
    partition_by=("detector", "running_mode", "take"),
)
