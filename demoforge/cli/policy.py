"""`demoforge` commands of the policy area (a sub-app composed into the root app)."""

from __future__ import annotations

from typing import List, Optional

import typer

from demoforge.cli.root import current_warehouse, fail
from demoforge.runtime.runners import run_flow

app = typer.Typer()


def _print_rows(sql: str, params: list | None = None) -> None:
    from demoforge.lib.evaluation.markdown import markdown_table
    from demoforge.schemas.catalog import query

    t = query(sql, current_warehouse(), params)
    typer.echo(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))


@app.command("train-policy")
def train_policy_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episode database to learn from."),
    take: Optional[str] = typer.Option(None, help="Episode database (source take); needed only when the task has several."),
    seed: int = typer.Option(0, help="Seed of the weights, the batch order and the train/validation split: same seed, same checkpoint."),
    epochs: int = typer.Option(40, min=1, help="Passes over the training episodes."),
    max_minutes: float = typer.Option(9.0, min=0.0, help="Wall-clock budget of the training loop: it stops after the epoch that passes it (0 = no budget). Only a run that finishes all its epochs is reproducible from the seed."),
    threads: int = typer.Option(1, min=1, help="torch CPU threads (1 leaves the other cores to the rest of the machine)."),
    batch_size: int = typer.Option(256, min=1, help="Episodes per optimizer step."),
    lr: float = typer.Option(1e-3, min=0.0, help="Peak learning rate (linear warm-up, cosine decay)."),
    d_model: int = typer.Option(64, min=8, help="Transformer width (a multiple of its 4 heads)."),
    layers: int = typer.Option(2, min=1, help="Encoder and decoder layers each."),
    waypoints: int = typer.Option(20, min=2, help="Waypoints per predicted action sequence (the prompts' count)."),
    val_fraction: float = typer.Option(0.1, min=0.01, max=0.9, help="Share of the sampled placements held out for validation."),
) -> None:
    """Train the keypoint-to-trajectory policy (a small Transformer) on a task's augmented episodes.

    Input: the scene's object keypoints and the initial gripper poses; output: the action sequence at
    the prompts' waypoint count (positions, 6D rotations, gripper open probability).  The checkpoint
    is stored in <warehouse>/_policy/, its validation errors in the `policy_checkpoints` table.
    """
    from demoforge.flows.policy import train_policy

    if d_model % 4:
        raise fail(f"--d-model must be a multiple of 4 (the attention heads), got {d_model}")
    try:
        run_flow(train_policy, str(current_warehouse()), task=task, take=take, seed=seed, epochs=epochs,
                 max_minutes=max_minutes or None, threads=threads, batch_size=batch_size, lr=lr, d_model=d_model,
                 layers=layers, val_fraction=val_fraction, n_waypoints=waypoints)
    except ValueError as e:
        raise fail(str(e))
    _print_rows("SELECT checkpoint_id, n_train, n_val, epochs_run, threads, round(train_seconds, 1) AS train_s, "
                "round(val_loss, 5) AS val_loss, round(val_pos_err_mm, 1) AS pos_mm, round(val_rot_err_deg, 2) AS rot_deg, "
                "round(val_grip_acc, 3) AS grip_acc FROM policy_checkpoints WHERE task = ? ORDER BY trained_at DESC LIMIT 1", [task])


@app.command("eval-policy")
def eval_policy_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task of the policy."),
    trials: int = typer.Option(10, min=1, help="Scenes per kind."),
    seed: int = typer.Option(0, help="Seed of the scenes (the same seed gives llm-eval's query scenes)."),
    take: Optional[str] = typer.Option(None, help="Episode database the policy was trained on; needed only when the task has several."),
    checkpoint: Optional[str] = typer.Option(None, help="Checkpoint id (kp-...); default: the newest of the task."),
    kind: Optional[List[str]] = typer.Option(None, "--kind", "-k", help="in_distribution, out_of_distribution, mirrored, held_out (repeatable; default all)."),
    threads: int = typer.Option(1, min=1, help="torch CPU threads for inference."),
) -> None:
    """Run a trained policy on new scenes and judge every prediction with the robot in MuJoCo.

    in_distribution = llm-eval's query scenes (also written to `llm_trials` as strategy `policy`, so
    Table 3 gains a row), mirrored = their mirror images, out_of_distribution = the demonstration's
    placement shifted beyond the augmentation's translation range, held_out = the database's own validation
    placements (the policy never trained on them).  Latency: one forward pass per scene.
    """
    from demoforge.flows.policy import evaluate_policy
    from demoforge.tasks.policy import SCENE_KINDS

    bad = [k for k in kind or [] if k not in SCENE_KINDS]
    if bad:
        raise fail(f"unknown --kind {bad[0]!r}; choose from {', '.join(SCENE_KINDS)}")
    try:
        run_flow(evaluate_policy, str(current_warehouse()), task=task, trials=trials, seed=seed, take=take,
                 checkpoint_id=checkpoint, kinds=list(kind or SCENE_KINDS), threads=threads)
    except ValueError as e:
        raise fail(str(e))
    _print_rows("SELECT checkpoint_id, scene_kind, count(*) AS trials, sum(success::INT) AS successes, "
                "round(avg(success::INT), 3) AS success_rate, round(median(latency_ms), 2) AS median_latency_ms "
                "FROM policy_trials WHERE task = ? GROUP BY ALL ORDER BY checkpoint_id, scene_kind", [task])
