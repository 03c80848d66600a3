"""`demoforge` commands of the policy area (a sub-app composed into the root app)."""

from __future__ import annotations

from typing import List, Optional

import typer

from demoforge.cli.root import TASK_HELP, current_warehouse, fail, gripper_option, robot_option, robot_spec
from demoforge.runtime.runners import run_flow

app = typer.Typer()


def _print_rows(sql: str, params: list | None = None) -> None:
    # lazy (CLI start-up): duckdb, pyarrow
    from demoforge.lib.evaluation.markdown import markdown_table
    from demoforge.schemas.catalog import query

    t = query(sql, current_warehouse(), params)
    typer.echo(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))


@app.command("train-policy")
def train_policy_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task whose episode database to learn from. " + TASK_HELP),
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
    closed_loop: bool = typer.Option(False, "--closed-loop", help="Train the closed-loop policy instead: action chunks "
                                     "from the arms' joints and the objects' keypoints at every step (ACT-style), on "
                                     "screened-in episodes in the arms' joint space."),
    episodes: int = typer.Option(100, min=1, help="--closed-loop: episodes to train on (1 = the original demonstration "
                                 "alone; else it and episodes the screening lets through, drawn with --seed)."),
    steps: int = typer.Option(3000, min=1, help="--closed-loop: optimizer steps (batches of 256 frames)."),
    robot: str = robot_option(default="aloha", help="--closed-loop: the arm robot whose joint space it acts in (one of: {robots})."),
    gripper: Optional[str] = gripper_option(default="2f140"),
) -> None:
    """Train the keypoint-to-trajectory policy (a small Transformer) on a task's augmented episodes.

    Input: the scene's object keypoints and the initial gripper poses; output: the action sequence at
    the prompts' waypoint count (positions, 6D rotations, gripper open probability).  The checkpoint
    is stored in <warehouse>/_policy/, its validation errors in the `policy_checkpoints` table.

    With --closed-loop: the policy a robot runs step by step. Input: the export's features at one frame
    (observation.state: the 14 joint values, observation.environment_state: the 11 object keypoints, the
    timestamp); output: the next 30 actions, averaged over overlapping predictions (ACT's temporal
    ensembling). Trained on --episodes episodes as the arms execute them; checkpoint in
    <warehouse>/_closed_loop/, its record in `closed_loop_checkpoints`; `demoforge eval-policy --closed-loop`
    rolls it out in the task's Gymnasium environment (demoforge.envs).
    """
    from demoforge.flows.policy import train_policy  # lazy: prefect

    if closed_loop:
        _train_closed_loop(task, take, episodes, seed, steps, robot, gripper, threads)
        return
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


def _train_closed_loop(task, take, episodes, seed, steps, robot, gripper, threads) -> None:
    from demoforge.flows.closed_loop import train_closed_loop  # lazy: prefect
    from demoforge.lib.task_library import get_task  # lazy (CLI start-up): numpy, scipy

    get_task(task)  # a typo: one line listing the tasks, before any flow starts
    spec = robot_spec(robot, gripper)
    try:
        run_flow(train_closed_loop, str(current_warehouse()), task=task, take=take, episodes=episodes, seed=seed,
                 steps=steps, robot=spec, gripper=None, threads=threads)
    except ValueError as e:  # a RobotError too
        raise fail(str(e))
    _print_rows("SELECT checkpoint_id, robot, n_requested, n_episodes, frames, steps, round(plan_seconds, 1) AS plan_s, "
                "round(train_seconds, 1) AS train_s, round(final_loss, 4) AS final_loss FROM closed_loop_checkpoints "
                "WHERE task = ? ORDER BY trained_at DESC LIMIT 1", [task])


@app.command("eval-policy")
def eval_policy_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task of the policy. " + TASK_HELP),
    trials: int = typer.Option(10, min=1, help="Scenes per kind."),
    seed: int = typer.Option(0, help="Seed of the scenes (the same seed gives llm-eval's query scenes)."),
    take: Optional[str] = typer.Option(None, help="Episode database the policy was trained on; needed only when the task has several."),
    checkpoint: Optional[str] = typer.Option(None, help="Checkpoint id (kp-...); default: the newest of the task."),
    kind: Optional[List[str]] = typer.Option(None, "--kind", "-k", help="in_distribution, out_of_distribution, mirrored, held_out (repeatable; default all)."),
    threads: int = typer.Option(1, min=1, help="torch CPU threads for inference."),
    closed_loop: bool = typer.Option(False, "--closed-loop", help="Roll out a closed-loop policy (train-policy "
                                     "--closed-loop) step by step in the task's Gymnasium environment instead."),
    scenes: int = typer.Option(50, min=1, help="--closed-loop: held-out scenes (thesis protocol, seeds no database uses)."),
) -> None:
    """Run a trained policy on new scenes and judge every prediction with the robot in MuJoCo.

    With --closed-loop: the newest closed-loop policy of the task (or --checkpoint cl-...) runs --scenes
    held-out scenes in the task's Gymnasium environment with the robot it was trained for; rows in
    `closed_loop_trials`, summed up in the view `report_data_scaling`.

    in_distribution = llm-eval's query scenes (also written to `llm_trials` as strategy `policy`, so
    Table 3 gains a row), mirrored = their mirror images, out_of_distribution = the demonstration's
    placement shifted beyond the augmentation's translation range, held_out = the database's own validation
    placements (the policy never trained on them).  Latency: one forward pass per scene.
    """
    # lazy: prefect
    from demoforge.flows.policy import evaluate_policy
    from demoforge.tasks.policy import SCENE_KINDS

    if closed_loop:
        _eval_closed_loop(task, checkpoint, scenes, seed)
        return
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


def _eval_closed_loop(task: str, checkpoint: Optional[str], scenes: int, seed: int) -> None:
    from demoforge.flows.closed_loop import eval_closed_loop, stored_checkpoint  # lazy: prefect
    from demoforge.lib.robot_spec import RobotSpec  # lazy (CLI start-up)

    try:
        manifest, row = stored_checkpoint(str(current_warehouse()), task, checkpoint)
        run_flow(eval_closed_loop, str(current_warehouse()), checkpoint=manifest, task=task, take=row["take"],
                 scenes=scenes, seed=seed, robot=RobotSpec.parse(row["robot"]), gripper=None)  # the row's label
    except ValueError as e:  # a RobotError too
        raise fail(str(e))
    _print_rows("SELECT * FROM report_data_scaling WHERE task = ?", [task])


@app.command("data-scaling")
def data_scaling_cmd(
    task: List[str] = typer.Option(["pouring"], "--task", "-t", help="Tasks (repeatable). " + TASK_HELP),
    sizes: str = typer.Option("1,10,100,1000", help="Numbers of episodes to train on, comma-separated (1 = the "
                              "original demonstration alone)."),
    scenes: int = typer.Option(50, min=1, help="Held-out scenes per task (thesis protocol, seeds no database uses)."),
    seed: int = typer.Option(0, help="Seed of the episode draws, the training and the scenes."),
    steps: int = typer.Option(3000, min=1, help="Optimizer steps per policy."),
    robot: str = robot_option(default="aloha", help="The arm robot (one of: {robots})."),
    gripper: Optional[str] = gripper_option(default="2f140"),
    threads: int = typer.Option(1, min=1, help="torch CPU threads for training."),
    baselines: bool = typer.Option(True, help="Also run the LLM-free baselines (replay_top1, transform_demo) and the "
                                   "open-loop keypoint policy (trained on every screened-in episode) on the same scenes."),
) -> None:
    """The data-scaling table: is a generated episode worth anything to a learner?

    Per task, a closed-loop policy (train-policy --closed-loop) trained on each number of episodes in
    --sizes, each rolled out on the same --scenes held-out scenes in the task's Gymnasium environment with
    the arms, beside the LLM-free baselines and the open-loop policy on those scenes. Rows: `closed_loop_trials`;
    the table with
    Wilson 95 % intervals: the view `report_data_scaling` (printed at the end, and in reports/REPORT.md)."""
    from demoforge.flows.closed_loop import data_scaling  # lazy: prefect
    from demoforge.lib.task_library import get_task  # lazy (CLI start-up): numpy, scipy

    for name in task:
        get_task(name)  # a typo: one line listing the tasks, before any flow starts
    try:
        n = [int(x) for x in sizes.split(",") if x.strip()]
    except ValueError:
        raise fail(f"--sizes must be comma-separated numbers of episodes, e.g. 1,10,100, got {sizes!r}")
    spec = robot_spec(robot, gripper)
    try:
        run_flow(data_scaling, str(current_warehouse()), tasks=list(task), sizes=n, scenes=scenes, seed=seed,
                 steps=steps, robot=spec, gripper=None, threads=threads, baselines=baselines, open_loop=baselines)
    except ValueError as e:  # a RobotError too
        raise fail(str(e))
    _print_rows("SELECT * FROM report_data_scaling")
