"""The `takes` table: one row per demonstration take known to the warehouse."""

import pyarrow as pa

from demoforge.schemas.core import Column, table

TAKES = table(
    "takes",
    version=1,
    doc="One row per demonstration take (synthetic or recorded) registered in the warehouse.",
    columns=[
        Column("take", pa.string(), "Take identifier (folder name), e.g. `synth_pouring_s0000` (`_m` = mirrored)."),
        Column("task", pa.string(), "Task name (`pouring`, `trash_in_bin`, `paper_in_case`, `mix_bowl`, `open_container`, `empty_vase`)."),
        Column("source", pa.string(), "`synthetic` (rendered by demoforge, exact ground truth) or `recorded` (a real RGB-D recording)."),
        Column("mirror", pa.bool_(), "Mirrored variant: the hands' roles are swapped."),
        Column("seed", pa.int64(), "Generator seed (synthetic takes); -1 for recorded takes."),
        Column("n_frames", pa.int32(), "Number of frames."),
        Column("fps", pa.float64(), "Frames per second."),
        Column("duration_s", pa.float64(), "n_frames / fps, s."),
        Column("path", pa.string(), "Absolute path of the take folder (rgb/, depth/, camera.json, ...)."),
        Column("generator", pa.string(), "What produced the take and its version, e.g. `demoforge.synth 1.0.0`."),
        Column("provenance", pa.string(), "Where the hand ground truth comes from, e.g. `ground truth (synthetic)`; never a detector's output."),
        Column("visible_left", pa.float64(), "Mean fraction of the left hand's 21 joints visible (depth test), 0-1.", nullable=True),
        Column("visible_right", pa.float64(), "Mean fraction of the right hand's 21 joints visible (depth test), 0-1.", nullable=True),
        Column("replay_success", pa.bool_(), "The scripted demonstration satisfied the task's success predicate when replayed in MuJoCo physics.", nullable=True),
        Column("replay_reason", pa.string(), "The predicate's explanation of success or failure.", nullable=True),
        Column("generate_seconds", pa.float64(), "Wall time to script, render and write the take, s."),
        Column("replay_seconds", pa.float64(), "Wall time of the physics replay, s.", nullable=True),
    ],
    partition_by=("task", "take"),
)
