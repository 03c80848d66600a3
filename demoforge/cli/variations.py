"""`demoforge variations`: the Table 4 analogue (a sub-app composed into the root app)."""

from __future__ import annotations

from typing import List, Optional

import typer

from demoforge.cli.root import TASK_HELP, current_warehouse, fail
from demoforge.runtime.runners import run_flow

app = typer.Typer()


@app.command("variations")
def variations_cmd(
    task: Optional[List[str]] = typer.Option(None, "--task", "-t", help="Task (repeatable; default pouring, mix_bowl, trash_in_bin: the thesis's Table 4 tasks). Each needs an episode database (`demoforge augment`). " + TASK_HELP),
    strategy: Optional[List[str]] = typer.Option(None, "--strategy", "-s", help="replay_top1 (the nearest database episode by keypoint MSE, replayed), transform_demo (the ingested demonstration transformed to the scene) or transform_scripted (a synthetic take's ground-truth demonstration transformed: no ingest error) (repeatable; default replay_top1 and transform_demo)."),
    kind: Optional[List[str]] = typer.Option(None, "--kind", "-k", help="nominal (the task's own placements), clutter (2-3 solid distractor bodies on the table), object (resized or reshaped objects of the same category), spatial (every object shifted 4-8 cm and turned 0.3-0.7 rad) (repeatable; default all four)."),
    trials: int = typer.Option(2, min=1, help="Scenes per task and variation kind (the thesis: 2-3)."),
    seed: int = typer.Option(0, help="Seed of the scenes; all kinds of one (seed, trial) start from the same placement."),
) -> None:
    """Success of the robot under simulated scene variations (thesis Table 4): clutter, other object
    instances, other spatial configurations; writes `variation_trials` and prints `report_table4`."""
    from demoforge.flows.variations import check_arguments, evaluate_variations  # lazy: prefect
    # lazy (CLI start-up): duckdb, numpy, pyarrow, scipy
    from demoforge.lib.evaluation.markdown import markdown_table
    from demoforge.lib.sim.variations import TABLE4_TASKS, VARIATION_KINDS
    from demoforge.schemas.catalog import query
    from demoforge.schemas.variations import REPORT_TABLE4_SQL

    args = dict(tasks=task or list(TABLE4_TASKS), strategies=strategy or ["replay_top1", "transform_demo"],
                kinds=kind or list(VARIATION_KINDS), trials=trials)
    try:
        check_arguments(**args)
        run_flow(evaluate_variations, str(current_warehouse()), seed=seed, **args)
    except ValueError as e:
        raise fail(str(e))
    t = query(REPORT_TABLE4_SQL, current_warehouse())
    typer.echo(markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
