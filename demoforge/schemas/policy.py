"""Tables of the learned keypoint-to-trajectory policy: its checkpoints and its evaluation trials."""

import pyarrow as pa

from demoforge.schemas.core import Column, keypoints3d, table

SCENE_KINDS = ("in_distribution", "out_of_distribution", "mirrored", "held_out")

POLICY_CHECKPOINTS = table(
    "policy_checkpoints",
    version=1,
    doc=("One trained policy: where its checkpoint lies (beside the warehouse tables, in `_policy/`), how it "
         "was trained (seed, epochs, threads, wall time) and its validation errors on held-out placements."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database it was trained on."),
        Column("checkpoint_id", pa.string(), "Short id of the trained weights (`kp-` + 10 hex digits of their sha256)."),
        Column("path", pa.string(), "Folder holding model.pt (config + weights) and config.json (config + training record)."),
        Column("seed", pa.int64(), "Seed of the initialisation, batch order and train/validation split."),
        Column("n_params", pa.int64(), "Trainable parameters."),
        Column("n_waypoints", pa.int32(), "Waypoints per predicted action sequence (the prompts' count)."),
        Column("n_train", pa.int32(), "Training episodes (valid episodes of the database minus validation)."),
        Column("n_val", pa.int32(), "Validation episodes: whole sampled placements held out."),
        Column("epochs_requested", pa.int32(), "Epochs asked for."),
        Column("epochs_run", pa.int32(), "Epochs run (fewer when the time budget stopped training)."),
        Column("steps", pa.int32(), "Optimizer steps."),
        Column("threads", pa.int32(), "torch CPU threads used for training."),
        Column("train_seconds", pa.float64(), "Wall time of the training loop, s (data loading excluded)."),
        Column("load_seconds", pa.float64(), "Wall time of reading and resampling the episode database, s."),
        Column("train_loss", pa.float64(), "Mean training loss of the last epoch."),
        Column("val_loss", pa.float64(), "Validation loss after training (normalised position MSE + 6D MSE + weighted gripper BCE)."),
        Column("val_pos_err_mm", pa.float64(), "Mean waypoint position error on validation, mm."),
        Column("val_rot_err_deg", pa.float64(), "Mean waypoint rotation error on validation, degrees."),
        Column("val_grip_acc", pa.float64(), "Fraction of validation waypoints with the right gripper state."),
        Column("train_loss_history", pa.list_(pa.float64()), "Training loss per epoch."),
        Column("val_loss_history", pa.list_(pa.float64()), "Validation loss per epoch."),
        Column("config", pa.string(), "Model and training configuration, JSON."),
        Column("trained_at", pa.timestamp("us", tz="UTC"), "When training finished (UTC); the newest checkpoint is the default for evaluation."),
    ],
    partition_by=("task", "take", "checkpoint_id"),
)

POLICY_TRIALS = table(
    "policy_trials",
    version=1,
    doc=("One policy prediction for one query scene, executed by the robot in MuJoCo. In-distribution scenes "
         "are the prompting evaluation's query scenes (same seed -> same scenes), mirrored scenes their mirror "
         "images, out-of-distribution scenes the original placement shifted beyond the augmentation's "
         "translation range, held-out scenes the database's own validation placements (never trained on)."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the database the policy was trained on."),
        Column("checkpoint_id", pa.string(), "The policy (see `policy_checkpoints`)."),
        Column("scene_kind", pa.string(), "`in_distribution`, `out_of_distribution`, `mirrored` or `held_out` (validation placements of the database)."),
        Column("trial", pa.int32(), "Scene number within its kind."),
        Column("seed", pa.int64(), "Seed of the scenes."),
        Column("query_keypoints", keypoints3d(11), "The scene's 11 object keypoints, world frame, m."),
        Column("in_augmented_region", pa.bool_(), "Every object's xy offset from the (mirrored) original placement lies inside the augmentation's translation box (yaw not compared)."),
        Column("max_offset_m", pa.float64(), "Largest xy distance of an object from its (mirrored) original placement, m."),
        Column("latency_ms", pa.float64(), "Inference time of the prediction (one forward pass, one scene), ms."),
        Column("predicted_waypoints", pa.list_(pa.list_(pa.list_(pa.float64(), 8), 2)), "The predicted (n, 2, 8) waypoints."),
        Column("success", pa.bool_(), "The executed trajectory passed the task's MuJoCo success check."),
        Column("failure_reason", pa.string(), "The simulator's failure class; empty on success."),
        Column("sim_detail", pa.string(), "The simulator's explanation."),
    ],
    partition_by=("task", "take", "checkpoint_id", "scene_kind"),
)
