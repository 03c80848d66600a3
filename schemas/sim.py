"""The `sim_results` table: each episode executed by the dual-gripper robot in MuJoCo physics; the
`sim_stability` table: the same check repeated on rigidly shifted copies of the scene.

Every `demoforge simulate` run writes under its own *selection* (`all`, `sample-20-seed0`,
`ids-<hash>`), so a 20-episode sample (as `make evaluate` runs) and a whole-database run never
overwrite each other's chunks. An episode checked by two runs therefore has two rows; the
`sim_outcomes` view keeps one per episode (the `all` run's where there is one).
"""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc

from demoforge.schemas.core import DATA_FILE, Column, read_parquet_file, register_migration, table, write_table

SIM_RESULTS = table(
    "sim_results",
    version=2,
    doc=("One row per episode and run (selection) executed by two parallel-jaw grippers (Robotiq 2F-140-like: "
         "140 mm stroke, 40 N per pad) in MuJoCo physics with real contacts, friction and gravity; objects are "
         "never welded. One row per episode: the `sim_outcomes` view."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
        Column("selection", pa.string(), "Which episodes the run checked: `all`, `sample-N-seedS` (N drawn with seed "
               "S, the original first), `ids-<hash>` (a given list), or `legacy` (written before runs had selections)."),
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
    partition_by=("task", "take", "selection", "chunk"),
)

SIM_STABILITY = table(
    "sim_stability",
    version=1,
    doc=("Outcome stability of the robot check: each episode executed `repeats` times, repeat 0 as is and the "
         "others with the whole scene (objects and gripper poses) shifted rigidly along the table by a fraction "
         "of a millimetre (`jitter_m`; lib/sim/stability.py). Physically nothing changes; an episode whose outcome flips "
         "is decided by numerical chaos, and its success is a probability. One row per episode and repeat."),
    columns=[
        Column("task", pa.string(), "Task name."),
        Column("take", pa.string(), "Source take of the episode database."),
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
    partition_by=("task", "take", "run", "chunk"),
)

LEGACY_SELECTION = "legacy"


def migrate_v1(root: str | os.PathLike) -> int:
    """Move version-1 files (`task=/take=/chunk=`, no selection) to selection `legacy` in the version-2
    layout; returns how many were moved. Version 1 wrote a sample run and a whole-database run into the
    same chunk files, so which run a v1 file came from is not recorded; its rows are kept as they are.
    Each file is written to its new place before the old one is removed (a crash leaves a copy that a
    re-run migrates again, never a loss); where the new place already holds rows, both are kept."""
    base = Path(root) / SIM_RESULTS.name
    moved = 0
    for old in sorted(base.glob(f"task=*/take=*/chunk=*/{DATA_FILE}")):
        t = read_parquet_file(old, SIM_RESULTS.name)
        if (t.schema.metadata or {}).get(b"demoforge.schema_version") != b"1":
            continue
        t = t.append_column("selection", pa.array([LEGACY_SELECTION] * t.num_rows, pa.string()))
        t = t.select(SIM_RESULTS.arrow.names).cast(SIM_RESULTS.arrow)
        chunk_dir = old.parent
        new = chunk_dir.parent / f"selection={LEGACY_SELECTION}" / chunk_dir.name / DATA_FILE
        if new.exists():
            # a crash after the copy, or an old process that kept writing v1 files after a migration:
            # keep every row, the v1 file's where both hold an episode (it was written later)
            existing = read_parquet_file(new, SIM_RESULTS.name).cast(SIM_RESULTS.arrow)
            keep = pc.invert(pc.is_in(existing.column("episode_id"), t.column("episode_id")))
            t = pa.concat_tables([existing.filter(keep), t]).sort_by("episode_id")
        write_table(SIM_RESULTS, t, root)  # validated, atomic, to exactly `new`
        old.unlink()
        try:
            chunk_dir.rmdir()
        except OSError:
            pass
        moved += 1
    return moved


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


register_migration(SIM_RESULTS.name, migrate_v1)
