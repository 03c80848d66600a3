"""Tables of the hand-keypoint evaluation (thesis 4.2, 5.1, Appendix B)."""

import pyarrow as pa

from demoforge.schemas.core import Column, metric_column as _m, table


KEYPOINT_METRICS = table(
    "keypoint_metrics",
    version=1,
    doc=("The thesis's keypoint metrics per take and hand, for one dataset (`arctic`, `synthetic`) and detector. "
         "Metrics over frames where the ground truth is valid and the hand was detected; NaN when none."),
    columns=[
        Column("dataset", pa.string(), "`arctic` (ARCTIC egocentric view) or `synthetic` (demoforge renders)."),
        Column("take", pa.string(), "Take / sequence name, e.g. `box_use_01` or `synth_pouring_s0000`."),
        Column("subject", pa.string(), "ARCTIC subject (`s01`...); empty for synthetic takes."),
        Column("object", pa.string(), "Manipulated object (ARCTIC object or task name)."),
        Column("size_group", pa.string(), "`big` (box, capsule machine, espresso machine) or `small` (ketchup, phone, scissors), as the thesis groups them; empty otherwise."),
        Column("hand", pa.string(), "`left` or `right`."),
        Column("detector", pa.string(), "Detector backend (`simulated` rows are never real detections)."),
        Column("detector_version", pa.string(), "Backend version."),
        Column("n_frames", pa.int32(), "Frames evaluated in the take (after ARCTIC's first/last 10 are skipped)."),
        Column("n_valid", pa.int32(), "Frames where the ground-truth hand is valid."),
        Column("n_detected", pa.int32(), "Frames where the detector found the hand."),
        Column("n_eval", pa.int32(), "Frames valid and detected (the metrics' denominator)."),
        Column("n_eval_aligned", pa.int32(), "Frames counted after depth alignment."),
        _m("detection_rate", "n_eval / n_valid."),
        _m("mpjpe_m", "MPJPE of the raw 3D prediction, camera frame, m (thesis eq. 4)."),
        _m("mpjpe_aligned_m", "MPJPE after depth alignment (anchor depth from depth maps, or from ground truth on ARCTIC: see `anchor_depth_source`), m."),
        _m("mpjpe_aligned_all_m", "The same including frozen and filled frames, m."),
        _m("pa_mpjpe_m", "PA-MPJPE: per-frame similarity Procrustes, then MPJPE, m (eq. 5)."),
        _m("pa_mpjpe_aligned_m", "PA-MPJPE of the aligned prediction, m."),
        _m("rr_mpjpe_m", "Root-relative MPJPE (wrist subtracted; ARCTIC's own convention), m."),
        _m("mpjpe_2d_px", "2D MPJPE of the 3D prediction projected with K, px (eq. 6)."),
        _m("pck05", "PCK@0.05 of the projected prediction, by ground-truth hand box size (eq. 7)."),
        _m("pck15", "PCK@0.15 of the projected prediction."),
        _m("mpjpe_2d_aligned_px", "2D MPJPE after alignment, px."),
        _m("pck05_aligned", "PCK@0.05 after alignment."),
        _m("pck15_aligned", "PCK@0.15 after alignment."),
        _m("mpjpe_2d_pred_px", "2D MPJPE of the detector's own 2D keypoints, px."),
        _m("pck05_pred", "PCK@0.05 of the detector's own 2D keypoints."),
        _m("pck15_pred", "PCK@0.15 of the detector's own 2D keypoints."),
        Column("n_swap_repaired", pa.int32(), "Frames whose left/right labels the alignment swapped back."),
        Column("n_outlier_frozen", pa.int32(), "Frames frozen by the outlier rule."),
        Column("alignment", pa.string(), "Alignment configuration used (`demoforge` defaults or `thesis`)."),
        Column("anchor_depth_source", pa.string(), "`depth` (the take's depth maps) or `ground_truth` (ARCTIC has no depth camera)."),
        Column("note", pa.string(), "What the reader must know about these numbers."),
    ],
    partition_by=("dataset", "take"),
)

REAL_PHOTO_METRICS = table(
    "real_photo_metrics",
    version=1,
    doc="A detector on the labelled real hand photos of ../shared/data/real_hands, per dataset (and `all`).",
    columns=[
        Column("dataset", pa.string(), "`freihand`, `onehand10k`, `panoptic`, `coco_wholebody` or `all`."),
        Column("detector", pa.string(), "Detector backend."),
        Column("images", pa.int32(), "Images evaluated."),
        Column("hands", pa.int32(), "Labelled hands."),
        Column("detected", pa.int32(), "Labelled hands matched by a detection."),
        _m("detection_rate", "detected / hands."),
        Column("handedness_known", pa.int32(), "Detected hands whose side the labels tell."),
        _m("handedness_acc", "Fraction of those with the right side."),
        _m("mpjpe_2d_px", "2D MPJPE over detected hands' labelled joints, px."),
        _m("pck05", "PCK@0.05 of the box size (detected hands)."),
        _m("pck15", "PCK@0.15 (detected hands)."),
        _m("pck20", "PCK@0.2 (detected hands)."),
        _m("pck05_all", "PCK@0.05 counting the joints of missed hands as wrong."),
        _m("pck15_all", "PCK@0.15 counting the joints of missed hands as wrong."),
        _m("pck20_all", "PCK@0.2 counting the joints of missed hands as wrong."),
    ],
    partition_by=("detector",),
)
