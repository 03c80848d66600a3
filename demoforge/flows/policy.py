"""Flows of the learned keypoint-to-trajectory policy: train it on a task's episode database, and
evaluate it beside the prompting strategies (Table 3) and on out-of-distribution and mirrored scenes."""

from __future__ import annotations

from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.lib.task_library import TASK_NAMES
from demoforge.schemas.core import WrittenFile, file_sha256, read_table, table_files
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.policy import SCENE_KINDS, database_inputs, database_takes, policy_eval, policy_train


def _resolve_take(warehouse: str, task: str, take: str | None) -> str:
    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    have = database_takes(warehouse, task)
    if not have:
        raise ValueError(f"no episode database for task {task!r}: run `demoforge augment` on a {task} take first")
    if take is None:
        if len(have) > 1:
            raise ValueError(f"task {task!r} has databases of several takes ({', '.join(have)}): choose one with take")
        return have[0]
    if take not in have:
        raise ValueError(f"no episode database of take {take!r} for {task!r}; there are: {', '.join(have)}")
    return take


@flow(name="train-policy")
def train_policy(warehouse: str, task: str = "pouring", take: str | None = None, seed: int = 0, epochs: int = 40,
                 max_minutes: float | None = 9.0, threads: int = 1, batch_size: int = 256, lr: float = 1e-3,
                 d_model: int = 64, layers: int = 2, val_fraction: float = 0.1, n_waypoints: int = 20,
                 robot_label: str | None = None, screening: Manifest | None = None) -> Manifest:
    """Train the keypoint policy on the valid episodes of the task's database (validation: 10 % of the
    sampled placements, held out whole; robot_label, an arm robot such as `aloha+2f140`: only the episodes
    its screening lets through, `screening` its manifest).  Stops after the epoch that passes `max_minutes`.
    The checkpoint goes to <warehouse>/_policy/<task>/<take>/<id>/, its record to `policy_checkpoints`;
    the same inputs and seed give the same weights (and a cache hit)."""
    if epochs < 1:
        raise ValueError("epochs must be at least 1")
    if threads < 1:
        raise ValueError("threads must be at least 1")
    take = _resolve_take(warehouse, task, take)
    m = run_stage(policy_train, warehouse, task=task, take=take, warehouse=warehouse,
                  database=database_inputs(warehouse, task, take), seed=seed, epochs=epochs,
                  max_seconds=None if max_minutes is None else 60.0 * max_minutes, threads=threads,
                  batch_size=batch_size, lr=lr, d_model=d_model, layers=layers, val_fraction=val_fraction,
                  n_waypoints=n_waypoints, robot_label=robot_label, screening=screening)
    get_run_logger().info("policy of %s/%s%s: %s", task, take, f" ({robot_label})" if robot_label else "", m.path)
    return m


def latest_checkpoint(warehouse: str, task: str, take: str, checkpoint_id: str | None = None) -> Manifest:
    """The manifest of a stored checkpoint: the given id, or the newest trained for task/take."""
    rows = read_table("policy_checkpoints", warehouse, task=task, take=take).to_pylist()
    if checkpoint_id is not None:
        rows = [r for r in rows if r["checkpoint_id"] == checkpoint_id]
    if not rows:
        which = f"checkpoint {checkpoint_id!r}" if checkpoint_id else "policy"
        raise ValueError(f"no trained {which} for {task}/{take}: run `demoforge train-policy --task {task}` first")
    row = max(rows, key=lambda r: r["trained_at"])
    f = table_files("policy_checkpoints", warehouse, task=task, take=take, checkpoint_id=row["checkpoint_id"])[0]
    return Manifest.from_written("policy_checkpoints", [WrittenFile("policy_checkpoints", str(f), 1, file_sha256(f))])


@flow(name="evaluate-policy")
def evaluate_policy(warehouse: str, task: str = "pouring", trials: int = 10, seed: int = 0, take: str | None = None,
                    checkpoint_id: str | None = None, kinds: Sequence[str] = SCENE_KINDS,
                    threads: int = 1) -> list[Manifest]:
    """Run the newest (or the given) policy of the task on `trials` scenes of each kind, executing every
    prediction in MuJoCo: in_distribution (the prompting evaluation's query scenes for this seed; also
    written to `llm_trials` as strategy `policy`), mirrored, out_of_distribution, held_out (validation
    placements of the database)."""
    if trials < 1:
        raise ValueError("trials must be at least 1")
    take = _resolve_take(warehouse, task, take)
    ck = latest_checkpoint(warehouse, task, take, checkpoint_id)
    out = run_stage(policy_eval, warehouse, task=task, take=take, warehouse=warehouse, checkpoint=ck,
                    trials=trials, seed=seed, kinds=list(kinds), threads=threads)
    get_run_logger().info("policy evaluation of %s/%s: %s", task, take, ", ".join(f"{m.table} {m.rows} rows" for m in out))
    return out
