"""Ground-truth tables written beside a synthetic take (``<take>/ground_truth/<table>.parquet``).

Written by :mod:`demoforge.lib.synth.take` with :func:`demoforge.schemas.core.write_table_file`. Frames of reference:
*world* = the table frame of docs/architecture.md (origin on the table top in front of the robot, z up,
y away from the robot, x to the robot's right; metres); *camera* = the head camera's OpenCV frame
(x right, y down, z forward; metres), related to the world by ``camera.json``'s ``T_world_camera``;
*px* = image pixels of the 640 x 480 RGB/depth frames, OpenCV convention (the centre of the
top-left pixel is (0, 0)). Hands: "left" = hand 0, "right" = hand 1. Frames are 0-based indices of
``rgb/NNNNNN.png``; ``time_s = frame / fps``.
"""

import pyarrow as pa

from demoforge.schemas.core import Column, keypoints2d, keypoints3d, matrix4, pose8, table

N_HAND_JOINTS = 21
N_OBJECT_KEYPOINTS = 11

_TAKE = Column("take", pa.string(), "Take identifier, e.g. `synth_pouring_s0003` (`_m` suffix when mirrored).")
_TASK = Column("task", pa.string(), "Task name from `demoforge.lib.task_library.TASK_NAMES`.")
_FRAME = Column("frame", pa.int32(), "0-based frame index (the file `rgb/<frame:06d>.png`).")
_TIME = Column("time_s", pa.float64(), "Time of the frame since the take's start, s (frame / fps).")
_HAND = Column("hand", pa.string(), "`left` (hand/arm 0) or `right` (hand/arm 1).")

GT_HAND_JOINTS = table(
    "gt_hand_joints",
    version=1,
    doc=(
        "Exact 3D/2D hand joints of a synthetic take: one row per frame and hand. 21 joints in "
        "MediaPipe order (0 wrist; 1-4 thumb CMC/MCP/IP/tip; 5-8 index; 9-12 middle; 13-16 ring; "
        "17-20 pinky) of the rendered capsule hand (joints lie on the bone axes, inside the flesh)."
    ),
    columns=[
        _TAKE, _TASK, _FRAME, _TIME, _HAND,
        Column("joints_world", keypoints3d(N_HAND_JOINTS), "21 x 3 joint positions in the world (table) frame, m."),
        Column("joints_camera", keypoints3d(N_HAND_JOINTS), "21 x 3 joint positions in the OpenCV camera frame, m (z = depth along the optical axis)."),
        Column("joints_px", keypoints2d(N_HAND_JOINTS), "21 x 2 projections (u, v) with camera.json's K, px; may lie outside the image."),
        Column("visible", pa.list_(pa.bool_(), N_HAND_JOINTS), "Per joint: projects inside the image and passes the depth test against the exact rendered depth (not more than the joint's flesh radius + 1 cm of something in front of it)."),
        Column("present", pa.bool_(), "The hand is in view: at least one joint projects inside the image in front of the camera."),
    ],
    partition_by=("task", "take"),
)

GT_GRIPPER = table(
    "gt_gripper",
    version=1,
    doc=(
        "The scripted gripper (pinch) trajectory the hands were posed from: one row per frame and "
        "hand. The pinch frame: origin = midpoint of thumb tip (4) and index tip (8), z = approach "
        "(hand base -> fingertips), x = thumb tip -> index tip, y = z x x. The thesis's mapping "
        "applied to gt_hand_joints recovers it exactly."
    ),
    columns=[
        _TAKE, _TASK, _FRAME, _TIME, _HAND,
        Column("pose", pose8(), "[x, y, z, qx, qy, qz, qw, g]: pinch position in the world frame (m), unit quaternion scalar-last (world from pinch), g = 1 open / 0 closed."),
        Column("aperture", pa.float64(), "Thumb-tip to index-tip distance, m."),
        Column("closed", pa.bool_(), "Gripper closed (grasping) in this frame: g == 0."),
        Column("held_object", pa.string(), "Name of the object this hand holds in this frame; null when none.", nullable=True),
    ],
    partition_by=("task", "take"),
)

GT_OBJECTS = table(
    "gt_objects",
    version=1,
    doc="Exact object poses of a synthetic take: one row per frame and object.",
    columns=[
        _TAKE, _TASK, _FRAME, _TIME,
        Column("object", pa.string(), "Object name (the task's `object_names`, the MJCF body name)."),
        Column("object_index", pa.int32(), "Index of the object in the task's `object_names`."),
        Column("pose", matrix4(), "4 x 4 object-to-world transform (body frame of the MJCF object), m."),
    ],
    partition_by=("task", "take"),
)

GT_OBJECT_KEYPOINTS = table(
    "gt_object_keypoints",
    version=1,
    doc=(
        "The task's 11 object keypoints (the thesis's prompt points), one row per frame; names "
        "and order as the task's `keypoint_names` (also listed in take.json)."
    ),
    columns=[
        _TAKE, _TASK, _FRAME, _TIME,
        Column("keypoints_world", keypoints3d(N_OBJECT_KEYPOINTS), "11 x 3 keypoints in the world frame, m."),
        Column("keypoints_camera", keypoints3d(N_OBJECT_KEYPOINTS), "11 x 3 keypoints in the OpenCV camera frame, m."),
        Column("keypoints_px", keypoints2d(N_OBJECT_KEYPOINTS), "11 x 2 projections (u, v) with K, px."),
    ],
    partition_by=("task", "take"),
)

GT_SEGMENTS = table(
    "gt_segments",
    version=1,
    doc="The scripted demo's motion/skill segments per hand (frames [start, end), end exclusive).",
    columns=[
        _TAKE, _TASK, _HAND,
        Column("kind", pa.string(), "`motion` (free-space approach/transport) or `skill` (contact-rich part)."),
        Column("start", pa.int32(), "First frame of the segment."),
        Column("end", pa.int32(), "One past the last frame of the segment (exclusive)."),
        Column("object", pa.string(), "Name of the object the segment acts on; null when none.", nullable=True),
    ],
    partition_by=("task", "take"),
)

GT_TABLES = ("gt_hand_joints", "gt_gripper", "gt_objects", "gt_object_keypoints", "gt_segments")
