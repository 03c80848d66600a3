"""Flow: success under simulated scene variations (the thesis's Table 4 analogue)."""

from __future__ import annotations

from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.lib.sim.variations import TABLE4_TASKS, VARIATIONS_VERSION, VARIATION_KINDS
from demoforge.lib.task_library import TASK_LIBRARY_VERSION, TASK_NAMES
from demoforge.schemas.catalog import query
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.variations import VARIATION_STRATEGIES, code_files, database_files, variation_trials


def check_arguments(tasks: Sequence[str], strategies: Sequence[str], kinds: Sequence[str], trials: int) -> None:
    """ValueError naming what is wrong (the CLI calls this before starting a flow run)."""
    for what, given, known in (("task", tasks, TASK_NAMES), ("strategy", strategies, VARIATION_STRATEGIES),
                               ("variation kind", kinds, VARIATION_KINDS)):
        if not given:
            raise ValueError(f"no {what} given; choose from {', '.join(known)}")
        bad = [x for x in given if x not in known]
        if bad:
            raise ValueError(f"unknown {what} {bad}; choose from {', '.join(known)}")
    if trials < 1:
        raise ValueError(f"trials must be at least 1, got {trials}")


@flow(name="evaluate-variations")
def evaluate_variations(
    warehouse: str,
    tasks: Sequence[str] = TABLE4_TASKS,
    trials: int = 2,
    strategies: Sequence[str] = ("replay_top1", "transform_demo"),
    seed: int = 0,
    kinds: Sequence[str] = VARIATION_KINDS,
    takes: Sequence[str] | None = None,
) -> list[Manifest]:
    """For each task with an episode database: `trials` seeded scenes per variation kind (nominal,
    clutter = distractor bodies on the table, object = resized / reshaped objects of the same category,
    spatial = shifted and turned placements), each executed by the robot in MuJoCo with the trajectory of
    every strategy (replay_top1, transform_demo, transform_scripted). Writes `variation_trials`; the
    `report_table4` view is the thesis's Table 4. Cached on the episode database's content."""
    logger = get_run_logger()
    check_arguments(tasks, strategies, kinds, trials)
    out = []
    for task in tasks:
        have = query("SELECT DISTINCT take FROM episodes WHERE task = ? ORDER BY take",
                     warehouse, [task]).column(0).to_pylist()
        use = [t for t in have if takes is None or t in takes]
        if not use:
            raise ValueError(f"no episode database for task {task!r}"
                             + (f" among takes {list(takes)}" if takes is not None else "")
                             + f": run `demoforge augment` on a {task} take first")
        for take in use:
            m = run_stage(variation_trials, warehouse, task=task, take=take, warehouse=warehouse,
                          database=database_files(warehouse, task, take), kinds=list(kinds),
                          strategies=list(strategies), trials=trials, seed=seed, code=code_files(),
                          library_version=TASK_LIBRARY_VERSION, variations_version=VARIATIONS_VERSION)
            logger.info("%s %s: %d variation trials", task, take, m.rows)
            out.append(m)
    return out
