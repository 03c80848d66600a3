"""`make bench`: every stage's benchmark against its baseline, written to `warehouse/benchmarks`."""

from __future__ import annotations

import secrets
import tempfile
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from prefect import flow, get_run_logger

from lib.benchmarking import BenchCase, BenchResult, git_commit, machine_info, run_case
from schemas.core import Column, TableSchema, keypoints3d, write_table

# Each stage registers a function quick -> list[BenchCase] here.
CASE_FACTORIES: dict[str, Callable[[bool], list[BenchCase]]] = {}


def register(stage: str) -> Callable:
    def deco(factory: Callable[[bool], list[BenchCase]]) -> Callable[[bool], list[BenchCase]]:
        CASE_FACTORIES[stage] = factory
        return factory

    return deco


# Not registered: a scratch table for the benchmark only, so it never shows in the catalog.
_SCRATCH = TableSchema("_bench_keypoints", 1, "warehouse benchmark scratch table", (
    Column("frame", pa.int64(), "row index"), Column("joints", keypoints3d(21), "random joints")))


@register("warehouse")
def _warehouse_cases(quick: bool) -> list[BenchCase]:
    rows = 20_000 if quick else 200_000

    def setup(n: int):
        rng = np.random.default_rng(0)
        joints = rng.normal(size=(n, 21, 3))
        frame = np.arange(n, dtype=np.int64)
        tmp = Path(tempfile.mkdtemp(prefix="demoforge-bench-"))

        def fast():
            return write_table(_SCRATCH, {"frame": frame, "joints": joints}, tmp / "fast")

        def baseline():
            # What one writes without the vectorised conversion: Python lists row by row.
            t = pa.table({"frame": frame.tolist(), "joints": [j.tolist() for j in joints]})
            t = t.cast(pa.schema([("frame", pa.int64()), ("joints", pa.list_(pa.list_(pa.float64(), 3), 21))]))
            (tmp / "base").mkdir(exist_ok=True)
            pq.write_table(t, tmp / "base" / "data.parquet", compression="zstd")
            return t.num_rows

        return fast, baseline

    return [
        BenchCase("warehouse", "validate+atomic write, 21x3 keypoints", rows, "rows",
                  "per-row Python lists -> pyarrow -> Parquet, no validation", setup),
    ]


@flow(name="benchmarks", log_prints=True)
def run_benchmarks(warehouse: str, stages: Iterable[str] | None = None, quick: bool = False) -> list[dict]:
    """Run the benchmark cases of the given stages (all by default) and append them to `benchmarks`."""
    logger = get_run_logger()
    wanted = list(stages) if stages else list(CASE_FACTORIES)
    unknown = [s for s in wanted if s not in CASE_FACTORIES]
    if unknown:
        raise ValueError(f"unknown benchmark stage(s) {unknown}; known: {sorted(CASE_FACTORIES)}")
    run_id = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + secrets.token_hex(3)
    machine, commit = machine_info(), git_commit(str(Path(__file__).resolve().parents[1]))
    results: list[BenchResult] = []
    for stage in wanted:
        for case in CASE_FACTORIES[stage](quick):
            logger.info("bench %s / %s (%d %s)", case.stage, case.name, case.size, case.unit)
            results.append(run_case(case))
    now = datetime.now(timezone.utc)
    rows = [
        {
            "run_id": run_id, "stage": r.stage, "case_name": r.case, "size": r.size, "unit": r.unit,
            "seconds": r.seconds, "baseline_seconds": r.baseline_seconds, "ratio": r.ratio,
            "items_per_second": r.items_per_second, "baseline": r.baseline, "repeats": r.repeats,
            "machine": machine, "git_commit": commit, "measured_at": now,
        }
        for r in results
    ]
    if rows:
        write_table("benchmarks", pa.Table.from_pylist(rows), warehouse)
    return rows
