"""The `benchmarks` table written by `make bench`."""

import pyarrow as pa

from demoforge.schemas.core import Column, table

BENCHMARKS = table(
    "benchmarks",
    version=1,
    doc=(
        "One row per benchmark case and run of `make bench`: the optimised stage and a "
        "straightforward baseline timed in the same process on the same input."
    ),
    columns=[
        Column("run_id", pa.string(), "Identifier of the `make bench` run (UTC timestamp + random suffix)."),
        Column("stage", pa.string(), "Pipeline stage the case measures, e.g. `geometry`, `warehouse`."),
        Column("case_name", pa.string(), "Benchmark case name within the stage."),
        Column("size", pa.int64(), "Work items per call (frames, poses, rows, episodes: see `unit`)."),
        Column("unit", pa.string(), "What `size` counts."),
        Column("seconds", pa.float64(), "Best-of-repeats wall time of the optimised implementation (s)."),
        Column("baseline_seconds", pa.float64(), "Best-of-repeats wall time of the baseline on the same input (s)."),
        Column("ratio", pa.float64(), "baseline_seconds / seconds: how many times faster than the baseline."),
        Column("items_per_second", pa.float64(), "size / seconds."),
        Column("baseline", pa.string(), "What the baseline is, in words."),
        Column("repeats", pa.int32(), "Timed repeats per implementation (the best is kept)."),
        Column("machine", pa.string(), "CPU model, core count and Python version of the machine."),
        Column("git_commit", pa.string(), "Commit of the code measured (`unknown` outside a git checkout)."),
        Column("measured_at", pa.timestamp("us", tz="UTC"), "When the case finished."),
    ],
    partition_by=("run_id",),
)
