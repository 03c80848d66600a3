"""`make bench`: every stage's benchmark against its baseline, written to `warehouse/benchmarks`.

The stages and where their cases live: :mod:`demoforge.bench.registry`; each stage's cases: its own
``cases_<stage>.py``; timing a case: :mod:`demoforge.bench.timing`."""

from __future__ import annotations

import secrets
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterable

import pyarrow as pa
from prefect import flow, get_run_logger

from demoforge.bench.registry import CASE_MODULES, cases_for
from demoforge.bench.timing import BenchResult, run_case
from demoforge.runtime.provenance import git_commit, machine_info
from demoforge.schemas.core import write_table


@flow(name="benchmarks", log_prints=True)
def run_benchmarks(warehouse: str, stages: Iterable[str] | None = None, quick: bool = False) -> list[dict]:
    """Run the benchmark cases of the given stages (all by default) and append them to `benchmarks`."""
    logger = get_run_logger()
    wanted = list(stages) if stages else list(CASE_MODULES)
    unknown = [s for s in wanted if s not in CASE_MODULES]
    if unknown:
        raise ValueError(f"unknown benchmark stage(s) {unknown}; known: {sorted(CASE_MODULES)}")
    run_id = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + secrets.token_hex(3)
    machine, commit = machine_info(), git_commit(str(Path(__file__).resolve().parents[1]))
    results: list[BenchResult] = []
    from tqdm.auto import tqdm

    for stage in wanted:
        cases = cases_for(stage, quick)
        # the progress of a run that takes minutes (Prefect's INFO log, where the cases used to be
        # named, is off by default): one bar per stage, the case being measured beside it
        with tqdm(total=len(cases), desc=f"bench {stage}", unit="case", leave=False) as bar:
            for case in cases:
                bar.set_postfix_str(f"{case.name} ({case.size} {case.unit})"[:60])
                logger.info("bench %s / %s (%d %s)", case.stage, case.name, case.size, case.unit)
                results.append(run_case(case))
                bar.update()
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
