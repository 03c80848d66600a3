"""The `sim_results` table: each episode executed by the dual-gripper robot in MuJoCo physics."""

import pyarrow as pa

from schemas.core import Column, table

SIM_RESULTS = table(
    "sim_results",
    version=1,
    doc=("One row per episode executed by two parallel-jaw grippers (Robotiq 2F-140-like: 140 mm stroke, "
         "40 N per pad) in MuJoCo physics with real contacts, friction and gravity; objects are never welded."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        Column("chunk", pa.int32(), "Chunk of the run that simulated the episode (a crash loses at most one chunk)."),
        Column("episode_id", pa.int64(), "Episode (see `episodes`)."),
        Column("kind", pa.string(), "`original`, `translated` or `mirrored`."),
        Column("success", pa.bool_(), "The task's success predicate held and no hard failure occurred."),
        Column("failure", pa.string(), "Empty on success, else `invalid_action`, `arm_collision`, `table_collision`, `left_workspace`, `missed_grasp`, `object_dropped` or `predicate_not_met`."),
        Column("detail", pa.string(), "The failure in words (when and which parts)."),
        Column("predicate_ok", pa.bool_(), "The predicate alone (null when the run stopped early at a hard failure).", nullable=True),
        Column("predicate_detail", pa.string(), "The predicate's explanation."),
        Column("duration_s", pa.float64(), "Simulated time, s."),
        Column("physics_steps", pa.int64(), "Physics steps taken."),
        Column("wall_s", pa.float64(), "Wall time of the episode in its worker process, s."),
    ],
    partition_by=("task", "take", "chunk"),
)
