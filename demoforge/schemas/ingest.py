"""Tables of the ingest flow: frames -> hand_keypoints -> aligned_keypoints -> gripper_poses, plus
object_keypoints and the per-take accuracy table `ingest_metrics` (synthetic takes only)."""

import pyarrow as pa

from demoforge.schemas.core import (
    Column, added_columns_migration, keypoints2d, keypoints3d, pose8, register_migration, table, vec3,
)

_TAKE = Column("take", pa.string(), "Take identifier (the take folder's name).")
_TASK = Column("task", pa.string(), "Task name, or `unknown` for a recorded take ingested without `--task`.")
_FRAME = Column("frame", pa.int32(), "0-based frame index.")
_HAND = Column("hand", pa.string(), "`left` (arm 0) or `right` (arm 1).")
_DETECTOR = Column("detector", pa.string(), "Hand detector backend that produced the keypoints (`simulated`, `mediapipe`, `precomputed`, ...). `simulated` rows are never real detections.")
_PARTS = ("task", "take")

FRAMES = table(
    "frames",
    version=1,
    doc="The take's frames as indexed by the ingest flow, with per-frame problems (never fatal for the take).",
    columns=[
        _TAKE, _TASK, _FRAME,
        Column("time_s", pa.float64(), "Timestamp since the take's start, s (frame / fps)."),
        Column("status", pa.string(), "`ok`, `missing_depth`, `missing_rgb`, `unreadable_rgb`, `unreadable_depth`, `depth_size_mismatch`, `all_zero_depth`; recordings also `dropped_frame` (the camera's timestamps skip it), `repeated_frame` (delivered twice, the copy discarded), `camera_moved` (Record3D: the camera > 1 cm from its first pose)."),
        Column("message", pa.string(), "What was wrong, in words (empty when ok)."),
        Column("rgb_source", pa.string(), "RGB file, or `<video>#<index>` for a frame of an .mp4, `<recording>#<index>` for a recording's; empty when missing."),
        Column("depth_source", pa.string(), "Depth file, or `<recording>#<index>`; empty when missing."),
    ],
    partition_by=_PARTS,
)

HAND_KEYPOINTS = table(
    "hand_keypoints",
    version=1,
    doc="The detector's most confident left and right hand per frame (the thesis's selection), before any correction.",
    columns=[
        _TAKE, _TASK, _FRAME, _HAND, _DETECTOR,
        Column("detector_version", pa.string(), "Version of the backend (model file, error model)."),
        Column("present", pa.bool_(), "A hand with this label was detected in the frame."),
        Column("confidence", pa.float64(), "Detector confidence of the selected hand, 0-1 (0 when absent)."),
        Column("joints_cam", keypoints3d(21), "21 x 3 joints in the OpenCV camera frame, m, as detected (NaN when absent)."),
        Column("joints_px", keypoints2d(21), "21 x 2 joints in pixels, as detected (NaN when absent)."),
        Column("n_candidates", pa.int32(), "Hands of this label the detector proposed in the frame (the best is kept)."),
    ],
    partition_by=_PARTS,
)

ALIGNED_KEYPOINTS = table(
    "aligned_keypoints",
    version=2,
    doc=("Hand keypoints after depth alignment (thesis 3.1.2: anchor joints read on the depth image, all 21 "
         "joints translated), left/right swap repair, outlier freeze and gap filling. Never NaN where `present`."),
    columns=[
        _TAKE, _TASK, _FRAME, _HAND, _DETECTOR,
        Column("present", pa.bool_(), "The output holds finite joints for this hand (detected, frozen or filled)."),
        Column("detected", pa.bool_(), "The hand was detected in this frame (after swap repair)."),
        Column("joints_cam", keypoints3d(21), "21 x 3 corrected joints in the OpenCV camera frame, m (NaN when not present)."),
        Column("joints_world", keypoints3d(21), "21 x 3 corrected joints in the world (table) frame, m (NaN when not present)."),
        Column("translation", vec3(), "Depth-alignment translation applied to the detected joints, camera frame, m (NaN when none)."),
        Column("anchors_used", pa.int64(), "Bit mask of the joints whose depth reading was used (bit j = joint j)."),
        Column("n_anchors_valid", pa.int32(), "Anchors with a valid robust depth reading."),
        Column("no_depth", pa.bool_(), "No usable depth at any anchor: the translation was carried over."),
        Column("depth_outlier", pa.bool_(), "The depth reading was rejected by the temporal check."),
        Column("outlier_frozen", pa.bool_(), "Frame judged an outlier (thesis MSE rule): the previous keypoints were kept."),
        Column("swap_repaired", pa.bool_(), "The detector's left/right labels were swapped back in this frame."),
        Column("filled_missing", pa.bool_(), "The hand was not detected; the joints were filled from neighbouring frames (gaps of at most the tracker's `max_gap_frames`)."),
        Column("track_id", pa.int32(), "Hand track (0, 1, ... per hand) whose span holds this frame; -1 outside every track (then the hand is absent)."),
        Column("rejected", pa.string(), "Why the detector's detection here was not used: `isolated` (no sustained track), `depth_inconsistent` (not on depth at a distance matching its size), `duplicate` (both labels on one hand); empty when used or none."),
        Column("depth_ratio", pa.float64(), "Depth read under the detection / depth its apparent size implies (about 1 for a real hand; NaN without a reading)."),
        Column("depth_problem", pa.string(), "The take's depth failed a check (`empty_depth`, `unit_mm_read_as_m`, `unit_m_read_as_mm`, `mostly_invalid_depth`, `misaligned_depth`) and the user accepted it (`--accept-bad-depth`): every row of the take carries the code. Empty when the depth passed."),
    ],
    partition_by=_PARTS,
)

GRIPPER_POSES = table(
    "gripper_poses",
    version=2,
    doc=("The thesis's hand-to-gripper mapping (3.1.3) per frame and arm: position = midpoint of thumb and "
         "index tips, orientation from the base (joints 0, 1) towards that midpoint, x from thumb to index."),
    columns=[
        _TAKE, _TASK, _FRAME, _HAND, _DETECTOR,
        Column("pose", pose8(), "[x, y, z, qx, qy, qz, qw, g] in the world frame: m, unit quaternion scalar-last, g from `state_method` (1 open, 0 closed)."),
        Column("valid", pa.bool_(), "The hand's keypoints were present, so the pose is defined (else the pose is NaN)."),
        Column("fingertip_distance", pa.float64(), "Thumb-tip to index-tip distance, m."),
        Column("g_threshold", pa.int8(), "Open/close by the thesis's fixed threshold on the fingertip distance."),
        Column("g_auto", pa.int8(), "Open/close by the automatic per-take method (see README)."),
        Column("g_manual", pa.int8(), "Open/close from the annotation's labelled frame ranges; null without annotation.", nullable=True),
        Column("state_method", pa.string(), "Which of the three gives `pose`'s g: `manual` when labelled ranges exist, else the configured method."),
        Column("depth_problem", pa.string(), "As in `aligned_keypoints`: the take's failed depth check the user accepted, empty when the depth passed."),
    ],
    partition_by=_PARTS,
)

OBJECT_KEYPOINTS = table(
    "object_keypoints",
    version=1,
    doc="The scene's object keypoints at the first frame, in the world frame.",
    columns=[
        _TAKE, _TASK,
        Column("keypoint", pa.int32(), "Index in the task's ordered keypoint list (0-based)."),
        Column("name", pa.string(), "Keypoint name from the annotation / task library."),
        Column("uv", keypoints2d(1), "The annotated pixel (1 x 2), px; NaN for ground-truth keypoints with no annotation."),
        Column("point_world", vec3(), "Back-projected position in the world frame, m (NaN when not valid)."),
        Column("valid", pa.bool_(), "A robust depth reading existed at the pixel."),
        Column("reason", pa.string(), "`ok`, or why the point is not valid (`outside the image`, `no valid depth in the window`, ...)."),
        Column("source", pa.string(), "`annotation+depth` (2D annotation back-projected with depth) or `ground truth` (synthetic)."),
    ],
    partition_by=_PARTS,
)

_DEPTH_MISSING = Column("depth_missing_fraction", pa.float64(), "Share of this hand's used detections with no depth "
                        "reading at its anchors (`no_depth` in `aligned_keypoints`; their depth is interpolated); NaN "
                        "when the hand was never used.")
_DEPTH_MISSING_FRAMES = Column("depth_missing_frame_fraction", pa.float64(), "Take-level: share of the frames with a used "
                               "hand detection where depth is missing at a hand (the ingest warns above the threshold "
                               "of docs/ingest.md); NaN without any.")

INGEST_METRICS = table(
    "ingest_metrics",
    version=2,
    doc=("Accuracy of the ingest on synthetic takes, against their exact ground truth, per take, detector and "
         "hand. Rows with detector `simulated` measure the pipeline under the simulated detector's error model."),
    columns=[
        _TAKE, _TASK, _DETECTOR, _HAND,
        Column("frames", pa.int32(), "Frames where the ground-truth hand is in view."),
        Column("detected_fraction", pa.float64(), "Fraction of those frames where the detector found this hand."),
        Column("mpjpe_raw_m", pa.float64(), "MPJPE of the detector's 3D joints before depth alignment, m."),
        Column("mpjpe_aligned_m", pa.float64(), "MPJPE after depth alignment, swap repair and outlier freeze, over frames where the hand was detected, m."),
        Column("pa_mpjpe_m", pa.float64(), "PA-MPJPE (per-frame similarity Procrustes) of the aligned joints, m."),
        Column("root_relative_mpjpe_m", pa.float64(), "MPJPE after subtracting the wrist (ARCTIC's convention), m."),
        Column("mpjpe_2d_px", pa.float64(), "2D MPJPE of the detector's pixel joints, px."),
        Column("pck_005", pa.float64(), "PCK@0.05 of the 2D joints, normalised by the ground-truth hand box size."),
        Column("pck_015", pa.float64(), "PCK@0.15 of the 2D joints."),
        Column("gripper_position_error_mm", pa.float64(), "Mean distance between the mapped and the true pinch point, mm."),
        Column("gripper_orientation_error_deg", pa.float64(), "Mean geodesic angle between the mapped and the true gripper rotation, deg."),
        Column("approach_axis_error_deg", pa.float64(), "Mean angle between the mapped and the true approach (z) axes, deg."),
        Column("open_close_acc_threshold", pa.float64(), "Open/close accuracy of the thesis's fixed threshold, 0-1."),
        Column("open_close_acc_auto", pa.float64(), "Open/close accuracy of the automatic per-take method, 0-1."),
        Column("open_close_acc_manual", pa.float64(), "Open/close accuracy of the labelled ranges (annotation), 0-1.", nullable=True),
        Column("swap_frames_injected", pa.int32(), "Frames where the simulated detector swapped the labels (take-level; 0 for real detectors)."),
        Column("swap_frames_repaired", pa.int32(), "Frames where the ingest swapped the labels back (take-level)."),
        Column("swap_frames_repaired_correctly", pa.int32(), "Repaired frames that were really swapped (take-level)."),
        _DEPTH_MISSING, _DEPTH_MISSING_FRAMES,
    ],
    partition_by=_PARTS,
)

HAND_PRESENCE = table(
    "hand_presence",
    version=2,
    doc=("Per take and hand: how much of the take the hand tracker (demoforge.lib.perception.tracking) could follow, and "
         "whether the hand's trajectory can be trusted. `demoforge augment` refuses to build episodes from an "
         "untrusted hand unless forced (`--allow-untrusted-hands`)."),
    columns=[
        _TAKE, _TASK, _DETECTOR, _HAND,
        Column("frames", pa.int32(), "Frames in the take."),
        Column("frames_detected", pa.int32(), "Frames where the detector reported this hand (after left/right identity repair)."),
        Column("frames_accepted", pa.int32(), "Detections that belong to a confirmed track (the only ones used)."),
        Column("frames_isolated", pa.int32(), "Detections rejected as isolated (no sustained track)."),
        Column("frames_depth_inconsistent", pa.int32(), "Detections rejected because the depth under them does not match their size."),
        Column("frames_duplicate", pa.int32(), "Detections dropped as a second label on the other hand."),
        Column("frames_filled", pa.int32(), "Frames filled between accepted detections (bounded gaps), flagged `filled_missing`."),
        Column("frames_tracked", pa.int32(), "Frames where the hand's trajectory has a value (accepted + filled + frozen)."),
        Column("tracks", pa.int32(), "Number of separate tracks of the hand."),
        Column("trusted", pa.bool_(), "The trajectory covers enough of the take to build episodes from."),
        Column("reason", pa.string(), "Why the hand is not trusted, in words (empty when trusted)."),
        Column("depth_problem", pa.string(), "The take's failed depth check the user accepted (empty when the depth passed)."),
        _DEPTH_MISSING, _DEPTH_MISSING_FRAMES,
    ],
    partition_by=_PARTS,
)

# Files written before the depth coverage was measured (v1): the columns exist, NaN (not measured).
for _table in (INGEST_METRICS, HAND_PRESENCE):
    register_migration(_table.name, added_columns_migration(
        _table.name, 1, {_DEPTH_MISSING.name: float("nan"), _DEPTH_MISSING_FRAMES.name: float("nan")}))

FOLDER_INGESTS = table(
    "folder_ingests",
    version=1,
    doc=("One row per take folder found by the `ingest-folder` flow (the scheduled deployment): whether it "
         "was ingested, and if not, why. A failed take never stops the others; fix it and the next run retries it."),
    columns=[
        Column("folder", pa.string(), "The watched folder (absolute path)."),
        _TAKE,
        Column("path", pa.string(), "The take folder (absolute path)."),
        Column("detector", pa.string(), "Hand detector backend used."),
        Column("status", pa.string(), "`ingested`, `needs_annotation` (ingested up to gripper poses; object "
               "keypoints wait for `demoforge annotate`) or `failed`."),
        Column("error", pa.string(), "Why the take failed, or what to annotate (empty when ingested)."),
        Column("gripper_rows", pa.int64(), "Rows written to `gripper_poses` for the take (0 when failed)."),
        Column("episodes", pa.int64(), "Episodes generated for the take when the flow augments (0 otherwise)."),
    ],
    partition_by=("take",),
)
