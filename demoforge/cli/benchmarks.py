"""`demoforge bench`: every stage's benchmark against its baseline."""

from __future__ import annotations

from typing import List, Optional
import typer

from demoforge.cli.root import current_warehouse, fail
from demoforge.runtime.runners import run_flow

app = typer.Typer()

# the registered stages (demoforge.bench.registry.CASE_MODULES; tests/bench/test_registry.py keeps the two equal)
STAGES = ("warehouse", "geometry", "synth", "takes", "ingest", "augmentation", "retrieval", "sim", "arms", "detection", "hamer",
          "exports", "policy", "llm")
STAGE_HELP = f"Only these stages (repeatable): {', '.join(STAGES)}. The llm stage takes minutes."


@app.command()
def bench(
    stage: Optional[List[str]] = typer.Option(None, "--stage", "-s", help=STAGE_HELP),
    quick: bool = typer.Option(False, help="Smaller inputs, for a fast smoke run."),
) -> None:
    """Benchmark every stage against a straightforward baseline; rows go to the `benchmarks` table."""
    from demoforge.bench.run import run_benchmarks  # lazy: prefect

    try:
        rows = run_flow(run_benchmarks, str(current_warehouse()), stages=stage, quick=quick)
    except ValueError as e:
        raise fail(str(e))
    header = f"{'stage':<12} {'case':<52} {'size':>9} {'unit':<9} {'seconds':>9} {'baseline s':>10} {'ratio':>8}"
    typer.echo(header)
    typer.echo("-" * len(header))
    for r in rows:
        typer.echo(
            f"{r['stage']:<12} {r['case_name'][:52]:<52} {r['size']:>9} {r['unit']:<9} "
            f"{r['seconds']:>9.4f} {r['baseline_seconds']:>10.4f} {r['ratio']:>7.1f}x"
        )
    if rows:
        typer.echo(f"machine: {rows[0]['machine']}; commit {rows[0]['git_commit']}; run {rows[0]['run_id']}")
