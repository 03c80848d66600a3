"""Tables of segmentation and augmentation (thesis 3.2-3.3): segments, episodes, episode_steps."""

import pyarrow as pa

from demoforge.schemas.core import Column, dual_pose8, keypoints3d, table

_TAKE = Column("take", pa.string(), "Source take of the demonstration.")
_TASK = Column("task", pa.string(), "Task name.")

SEGMENTS = table(
    "segments",
    version=1,
    doc="Motion and skill segments of each arm's gripper trajectory of an ingested take.",
    columns=[
        _TAKE, _TASK,
        Column("arm", pa.int8(), "0 = left, 1 = right."),
        Column("kind", pa.string(), "`motion` (free space) or `skill` (near or holding its object)."),
        Column("start", pa.int32(), "First frame of the segment."),
        Column("end", pa.int32(), "One past the last frame (exclusive)."),
        Column("object", pa.int32(), "Index of the object the segment is relative to (task library order); -1 = none."),
        Column("method", pa.string(), "`auto` (gripper state + distance to the object's keypoints) or `manual` (given boundaries)."),
    ],
    partition_by=("task", "take"),
)

SEGMENTATION_METRICS = table(
    "segmentation_metrics",
    version=1,
    doc="Segment boundaries found on an ingested synthetic take against its scripted boundaries.",
    columns=[
        _TAKE, _TASK,
        Column("arm", pa.int8(), "0 = left, 1 = right."),
        Column("boundaries_true", pa.int32(), "Scripted boundaries of this arm."),
        Column("boundaries_found", pa.int32(), "Boundaries found by the segmentation."),
        Column("matched", pa.int32(), "Found boundaries matched to a scripted one (within 30 frames)."),
        Column("mean_error_frames", pa.float64(), "Mean |found - scripted| over matched boundaries, frames.", nullable=True),
        Column("max_error_frames", pa.float64(), "Largest matched boundary error, frames.", nullable=True),
    ],
    partition_by=("task", "take"),
)

EPISODES = table(
    "episodes",
    version=1,
    doc=("One row per episode of a task database: the original demonstration (episode 0), translated "
         "episodes and mirrored-and-translated episodes (thesis 3.2-3.3)."),
    columns=[
        _TASK, _TAKE,
        Column("episode_id", pa.int64(), "Episode number within (task, take); 0 = the original demonstration."),
        Column("kind", pa.string(), "`original`, `translated` or `mirrored` (mirrored across x = 0, arms swapped, then translated)."),
        Column("seed", pa.int64(), "Seed of the sampling run that produced the episode."),
        Column("transform", pa.list_(pa.list_(pa.float64(), 3), 2), "Per object [dx m, dy m, dyaw rad] applied to the object (after mirroring for `mirrored`)."),
        Column("object_keypoints", keypoints3d(11), "11 x 3 object keypoints of the episode's scene at its start, world frame, m (task keypoint order)."),
        Column("initial_poses", dual_pose8(), "2 x 8 initial gripper poses [x, y, z, qx, qy, qz, qw, g] (arm 0 = left)."),
        Column("length", pa.int32(), "Number of steps (rows in `episode_steps`)."),
        Column("valid", pa.bool_(), "Passed the checks: poses inside the workspace, grippers never closer than the safety distance, objects apart."),
        Column("reject_reason", pa.string(), "Why the episode is not valid (`left_workspace`, `grippers_too_close`, `objects_overlap`); empty when valid."),
        Column("min_gripper_distance", pa.float64(), "Smallest distance between the two grippers over the episode, m."),
    ],
    partition_by=("task", "take"),
)

EPISODE_STEPS = table(
    "episode_steps",
    version=1,
    doc="The action sequence of every episode, one row per step (30 steps per second).",
    columns=[
        _TASK, _TAKE,
        Column("episode_id", pa.int64(), "Episode number (see `episodes`)."),
        Column("step", pa.int32(), "0-based step."),
        Column("action", pa.list_(pa.list_(pa.float32(), 8), 2), "2 x 8 gripper poses [x, y, z, qx, qy, qz, qw, g], world frame, m (float32: 0.1 µm resolution at 1 m)."),
    ],
    partition_by=("task", "take"),
)
