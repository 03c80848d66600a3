"""The `sim_results` table: each episode executed by a robot (lib/sim/robots) in MuJoCo physics; the
`sim_stability` table: the same check repeated on rigidly shifted copies of the scene.

Every `demoforge simulate` run writes under its own *selection* (`all`, `sample-20-seed0`,
`ids-<hash>`), so a 20-episode sample (as `make evaluate` runs) and a whole-database run never
overwrite each other's chunks, and so does each robot (`robot`, `gripper`). An episode checked by two
runs therefore has two rows; the `sim_outcomes` view keeps one per episode and robot (the `all` run's
where there is one).
"""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa

from demoforge.schemas.core import (DATA_FILE, Column, parquet_metadata, read_parquet_file, register_migration, table,
                                    write_table)

ROBOT_COLUMNS = [
    Column("robot", pa.string(), "The robot that executed the episode (lib/sim/robots): `grippers` (two free-floating "
           "grippers welded to mocap targets) or `aloha` (two ViperX 300 6-DOF arms driven in joint space)."),
    Column("gripper", pa.string(), "Its hands: `2f140` (Robotiq 2F-140-like, 140 mm stroke, opens 110 mm) or `aloha` "
           "(the ViperX gripper with ALOHA's fingers, 69 mm between the pads)."),
]

SIM_RESULTS = table(
    "sim_results",
    version=4,
    doc=("One row per episode, robot and run (selection) executed in MuJoCo physics with real contacts, friction and "
         "gravity; objects are never welded. `robot` says which: the two floating grippers or the two ALOHA arms "
         "(with their inverse kinematics' residual). One row per episode and robot: the `sim_outcomes` view."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        *ROBOT_COLUMNS,
        Column("selection", pa.string(), "Which episodes the run checked: `all`, `sample-N-seedS` (N drawn with seed "
               "S, the original first), `ids-<hash>` (a given list), or `legacy` (written before runs had selections)."),
        Column("chunk", pa.int32(), "Chunk of the run that simulated the episode (a crash loses at most one chunk)."),
        Column("episode_id", pa.int64(), "Episode (see `episodes`)."),
        Column("kind", pa.string(), "`original`, `translated` or `mirrored`."),
        Column("success", pa.bool_(), "The task's success predicate held and no hard failure occurred."),
        Column("failure", pa.string(), "Empty on success, else `invalid_action`, `arm_collision`, `table_collision`, "
               "`left_workspace`, `missed_grasp`, `object_dropped`, `predicate_not_met`; with arms also `unreachable`, "
               "`joint_limit`, `link_collision`; `wider_than_stroke` (an object the hand cannot open around)."),
        Column("detail", pa.string(), "The failure in words (when and which parts)."),
        Column("predicate_ok", pa.bool_(), "The predicate alone (null when the run stopped early at a hard failure).", nullable=True),
        Column("predicate_detail", pa.string(), "The predicate's explanation."),
        Column("reachable", pa.bool_(), "Arms only: every step's pinch poses are within 1 cm and 5 degrees of their "
               "targets after inverse kinematics (null for the grippers, which reach every pose).", nullable=True),
        Column("ik_position_error_m", pa.float64(), "Arms only: the worst pinch position residual after inverse "
               "kinematics over the episode's steps, m, up to the first step off its target when there is one (the "
               "simulation stops there) (null for the grippers).", nullable=True),
        Column("ik_rotation_error_deg", pa.float64(), "Arms only: the worst pinch orientation residual after inverse "
               "kinematics, degrees, the same steps (null for the grippers).", nullable=True),
        Column("time_scale", pa.float64(), "Arms only: the executed duration over the demonstrated duration: the "
               "arms start at their ready pose and slow the episode wherever a joint would exceed its servo's speed "
               "(1.0 and the ready pose's one frame: nothing slowed; lib/sim/robots/retiming.py) (null for the "
               "grippers).", nullable=True),
        Column("duration_s", pa.float64(), "Simulated time, s."),
        Column("physics_steps", pa.int64(), "Physics steps taken."),
        Column("wall_s", pa.float64(), "Wall time of the episode in its worker process, s."),
    ],
    partition_by=("task", "take", "robot", "gripper", "selection", "chunk"),
)

SIM_STABILITY = table(
    "sim_stability",
    version=2,
    doc=("Outcome stability of the robot check: each episode executed `repeats` times, repeat 0 as is and the "
         "others with the whole scene (objects and gripper poses) shifted rigidly along the table by a fraction "
         "of a millimetre (`jitter_m`; lib/sim/stability.py). Physically nothing changes; an episode whose outcome flips "
         "is decided by numerical chaos, and its success is a probability. One row per episode, robot and repeat."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        *ROBOT_COLUMNS,
        Column("run", pa.string(), "The stability run: its episode selection (as in `sim_results`), repeats, "
               "jitter and seed, e.g. `sample-40-seed0-r5-j0.0001-s0`."),
        Column("chunk", pa.int32(), "Chunk of the run (a crash loses at most one chunk)."),
        Column("episode_id", pa.int64(), "Episode (see `episodes`)."),
        Column("kind", pa.string(), "`original`, `translated` or `mirrored`."),
        Column("repeat", pa.int32(), "0: the unshifted scene (the run `simulate` checks); 1..: shifted."),
        Column("jitter_m", pa.float64(), "Standard deviation of the shift in x and y, m."),
        Column("offset_x", pa.float64(), "The repeat's shift in x, m."),
        Column("offset_y", pa.float64(), "The repeat's shift in y, m."),
        Column("success", pa.bool_(), "The robot check succeeded (as in `sim_results`)."),
        Column("failure", pa.string(), "Empty on success, else the failure class (as in `sim_results`)."),
        Column("detail", pa.string(), "The failure in words."),
        Column("wall_s", pa.float64(), "Wall time of the execution in its worker process, s."),
    ],
    partition_by=("task", "take", "robot", "gripper", "run", "chunk"),
)

LEGACY_SELECTION = "legacy"
# what every row written before robots had a name was executed by
LEGACY_ROBOT = {"robot": "grippers", "gripper": "2f140"}


def _upgrade(schema, t: pa.Table, extra: dict) -> pa.Table:
    """Rows of an older contract in the current one: the given constant columns added, the columns the
    older contract did not have (arms only) null."""
    for name, value in {**LEGACY_ROBOT, **extra}.items():
        if name not in t.column_names:
            t = t.append_column(name, pa.array([value] * t.num_rows, pa.string()))
    for field in schema.arrow:
        if field.name not in t.column_names:
            t = t.append_column(field.name, pa.nulls(t.num_rows, field.type))
    return t.select(schema.arrow.names).cast(schema.arrow)


def _migrate(root: str | os.PathLike, schema, old_versions: dict[bytes, tuple[str, dict]]) -> int:
    """Move every file of an older version of `schema` (a key of old_versions, whose value is the
    version's folder layout (a glob) and the constant columns its rows lack) to the current layout;
    returns how many were moved. Each file is written to its new place before the old one is removed
    (a crash leaves a copy that a re-run migrates again, never a loss); where the new place already
    holds rows, both are kept, the old file's where both hold an episode (and repeat), as it was
    written later."""
    base = Path(root) / schema.name
    keys = ["episode_id"] + (["repeat"] if "repeat" in schema.arrow.names else [])
    moved = 0
    olds = sorted({p for layout, _ in old_versions.values() for p in base.glob(f"{layout}/{DATA_FILE}")})
    for old in olds:
        version = (parquet_metadata(old, schema.name).metadata or {}).get(b"demoforge.schema_version", b"")
        if version not in old_versions:
            continue
        t = _upgrade(schema, read_parquet_file(old, schema.name), old_versions[version][1])
        new = base.joinpath(*(f"{k}={t.column(k)[0].as_py()}" for k in schema.partition_by)) / DATA_FILE
        if new == old:  # the same layout (a column added): rewritten in place, atomically
            write_table(schema, t, root)
            moved += 1
            continue
        if new.exists():
            existing = read_parquet_file(new, schema.name)
            existing = _upgrade(schema, existing, {})
            newer = set(zip(*(t.column(k).to_pylist() for k in keys)))
            keep = [k not in newer for k in zip(*(existing.column(c).to_pylist() for c in keys))]
            t = pa.concat_tables([existing.filter(pa.array(keep, pa.bool_())), t]).sort_by(keys[0])
        write_table(schema, t, root)  # validated, atomic, to exactly `new`
        old.unlink()
        d = old.parent
        while d != base:  # the old layout's folders, now empty
            try:
                d.rmdir()
            except OSError:
                break
            d = d.parent
        moved += 1
    return moved


def migrate_sim_results(root: str | os.PathLike) -> int:
    """Version 1 (`task=/take=/chunk=`, no selection: moved to selection `legacy`), version 2 (before robots
    had names: `robot` = grippers, `gripper` = 2f140, the arms' columns null) and version 3 files (before
    `time_scale`: null, rewritten in place) to version 4. Version 1 wrote a sample run and a whole-database
    run into the same chunk files, so which run a v1 file came from is not recorded; its rows are kept as
    they are."""
    return _migrate(root, SIM_RESULTS, {b"1": ("task=*/take=*/chunk=*", {"selection": LEGACY_SELECTION}),
                                        b"2": ("task=*/take=*/selection=*/chunk=*", {}),
                                        b"3": ("task=*/take=*/robot=*/gripper=*/selection=*/chunk=*", {})})


def migrate_sim_stability(root: str | os.PathLike) -> int:
    """Version 1 files (before robots had names) to version 2: `robot` = grippers, `gripper` = 2f140."""
    return _migrate(root, SIM_STABILITY, {b"1": ("task=*/take=*/run=*/chunk=*", {})})


def drop_results(root: str | os.PathLike, task: str, take: str) -> int:
    """Remove every `sim_results` and `sim_stability` file of one take (all selections and runs), e.g.
    when its episodes were regenerated; returns how many. Each table's take folder is first moved out of
    the table (to `<root>/_trash/`, on the same file system), so a reader sees all of its files or none,
    and a crash before the deletion leaves nothing in the table."""
    import shutil
    import uuid

    n = 0
    for name in (SIM_RESULTS.name, SIM_STABILITY.name):
        d = Path(root) / name / f"task={task}" / f"take={take}"
        if not d.is_dir():
            continue
        n += sum(1 for _ in d.rglob(DATA_FILE))
        trash = Path(root) / "_trash" / f"{name}-{uuid.uuid4().hex}"
        trash.parent.mkdir(exist_ok=True)
        d.rename(trash)
        shutil.rmtree(trash, ignore_errors=True)
    return n


register_migration(SIM_RESULTS.name, migrate_sim_results)
register_migration(SIM_STABILITY.name, migrate_sim_stability)
