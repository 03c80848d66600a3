"""Tables of the closed-loop policy (lib/policy/chunking.py) and of the data-scaling evaluation: its
checkpoints, and every rollout of it, of the open-loop policy and of the LLM-free baselines on held-out
scenes in the task's Gymnasium environment (demoforge.envs)."""

import pyarrow as pa

from demoforge.schemas.core import Column, table
from demoforge.schemas.report_section import ReportSection

METHODS = ("closed_loop", "open_loop", "replay_top1", "transform_demo")

CLOSED_LOOP_CHECKPOINTS = table(
    "closed_loop_checkpoints",
    version=1,
    doc=("One closed-loop policy trained on a number of a database's screened-in episodes in an arm robot's joint "
         "space: where its checkpoint lies (in `_closed_loop/`), what it was trained on and how long it took."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        Column("robot", pa.string(), "The arm robot, by its label (`aloha+2f140`)."),
        Column("gripper", pa.string(), "Its hands (`2f140`, `aloha`)."),
        Column("checkpoint_id", pa.string(), "Short id of the weights (`cl-` + 10 hex digits of their sha256)."),
        Column("path", pa.string(), "Folder holding model.pt and config.json."),
        Column("n_requested", pa.int32(), "Episodes asked for: 1 = the original demonstration alone, else the "
               "original and n - 1 screened-in episodes drawn with the seed."),
        Column("n_episodes", pa.int32(), "Episodes trained on: those of the requested the arms' IK reaches."),
        Column("frames", pa.int64(), "Training frames (30 fps)."),
        Column("seed", pa.int64(), "Seed of the episode draw, the weights and the batches."),
        Column("steps", pa.int32(), "Optimizer steps."),
        Column("threads", pa.int32(), "torch CPU threads."),
        Column("plan_seconds", pa.float64(), "Wall time of planning the episodes' joint trajectories, s."),
        Column("train_seconds", pa.float64(), "Wall time of the training loop, s."),
        Column("final_loss", pa.float64(), "Mean loss over the last tenth of the steps (L1 of the normalised joint "
               "changes + 0.5 x the grippers' BCE)."),
        Column("config", pa.string(), "Model and training configuration, JSON."),
        Column("trained_at", pa.timestamp("us", tz="UTC"), "When training finished (UTC)."),
    ],
    partition_by=("task", "take", "gripper", "checkpoint_id"),
)

CLOSED_LOOP_TRIALS = table(
    "closed_loop_trials",
    version=1,
    doc=("One rollout on one held-out scene (thesis protocol: the database's augmentation sampler with scene "
         "seeds no database uses) with an arm robot in MuJoCo: the closed-loop policy stepping the task's Gymnasium "
         "environment, or an LLM-free baseline executed by the robot check on the same scene."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        Column("robot", pa.string(), "The arm robot's label."),
        Column("gripper", pa.string(), "Its hands."),
        Column("method", pa.string(), "`closed_loop` (the chunk policy in the environment), `open_loop` (the keypoint-to-trajectory policy's "
               "waypoints for the scene, executed by the robot check), `replay_top1` (the "
               "nearest screened-in episode replayed), `transform_demo` (the demonstration carried to the scene)."),
        Column("checkpoint_id", pa.string(), "The closed-loop policy (see `closed_loop_checkpoints`), the open-loop "
               "policy's (`policy_checkpoints`), `none` for a baseline."),
        Column("n_train_episodes", pa.int32(), "Episodes the policy was trained on (the open-loop policy: all "
               "screened-in valid episodes less its validation placements); for a baseline, the episodes it chooses "
               "from (the screened-in database and the original)."),
        Column("scene_seed", pa.int64(), "Seed of the scene (the same seed, the same scene for every method)."),
        Column("scene_mirrored", pa.bool_(), "The scene has the demonstration's mirrored layout."),
        Column("success", pa.bool_(), "The task's success predicate held at the end, no failure."),
        Column("failure", pa.string(), "The robot check's failure class; empty on success."),
        Column("detail", pa.string(), "The simulator's explanation."),
        Column("frames", pa.int32(), "Frames run (30 fps)."),
        Column("rollout_seconds", pa.float64(), "Wall time of the rollout (inference and physics), s."),
        Column("inference_ms_per_step", pa.float64(), "The policy's mean inference time per step, ms (0 for a "
               "baseline)."),
    ],
    partition_by=("task", "take", "gripper", "method", "checkpoint_id"),
)

#: The `report_data_scaling` view: success per task, robot, method and training-set size, Wilson 95 % interval.
REPORT_DATA_SCALING_SQL = """
    WITH s AS (
        SELECT task, robot, method, n_train_episodes, count(*) AS n, count(*) FILTER (WHERE success) AS k,
               count(DISTINCT take) AS takes, avg(inference_ms_per_step) AS ms
        FROM closed_loop_trials GROUP BY task, robot, method, n_train_episodes
    ), w AS (SELECT *, k / n AS p, 1.96 AS z FROM s)
    SELECT task, robot, method, n_train_episodes, takes, n AS scenes, k AS successes, round(p, 3) AS success_rate,
           round(greatest(0.0, (p + z * z / (2 * n) - z * sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)), 3) AS wilson_low,
           round(least(1.0, (p + z * z / (2 * n) + z * sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)), 3) AS wilson_high,
           round(ms, 2) AS inference_ms_per_step
    FROM w ORDER BY task, robot, method <> 'closed_loop', method, n_train_episodes
"""

REPORT_DATA_SCALING = ReportSection(
    "report_data_scaling", "Data scaling: a closed-loop policy trained on generated episodes",
    computed_from=("closed_loop_trials",),
    intro=("Success of the closed-loop policy (`demoforge train-policy --closed-loop`: action chunks from the "
           "arms' joints and the objects' keypoints at every step, ACT-style) trained on 1 (the original "
           "demonstration), 10, 100, ... generated episodes the arms' screening lets through, rolled out step "
           "by step in the task's Gymnasium environment (demoforge.envs) on held-out scenes (thesis protocol, "
           "scene seeds no database uses), beside the LLM-free baselines and the open-loop keypoint policy "
           "(`open_loop`, trained on every screened-in episode) executed on the same scenes. `n_train_episodes` "
           "of a baseline: the episodes it chooses from. Wilson 95 % intervals."),
    if_empty="_Not run in this warehouse: `demoforge data-scaling`._",
    figure="data_scaling",
    sql=REPORT_DATA_SCALING_SQL,
)
