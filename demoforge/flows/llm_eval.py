"""Flow: the prompting-strategy evaluation (thesis Table 3) for one task."""

from __future__ import annotations

from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.lib.task_library import TASK_NAMES
from demoforge.schemas.catalog import query
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.llm_eval import BASELINES, LLM_STRATEGIES, keyframe_key, llm_trials

ALL_STRATEGIES = LLM_STRATEGIES + BASELINES


@flow(name="llm-eval")
def llm_eval(
    warehouse: str,
    task: str = "pouring",
    strategies: Sequence[str] = ALL_STRATEGIES,
    backend: str = "local",
    backend_options: dict | None = None,
    trials: int = 3,
    seed: int = 0,
    takes: Sequence[str] | None = None,
    n_waypoints: int | None = None,
    precision: int = 3,
    max_tokens: int | None = None,
    structured: bool | None = None,
    number_format: str | None = None,
) -> list[Manifest]:
    """Predict trajectories for `trials` seeded query scenes per take and strategy and judge each in
    MuJoCo. Strategies: single / random / retrieval (the thesis's three prompts, through `backend`),
    and the LLM-free baselines replay_top1 and transform_demo. Answers are cached: a re-run is free.
    `structured`: grammar / JSON-schema constrained answers (None: on for the local backend).
    `number_format`: thesis (None: metres, Appendix A) or compact (mm / hundredths as integers)."""
    logger = get_run_logger()
    unknown = [s for s in strategies if s not in ALL_STRATEGIES]
    if unknown:
        raise ValueError(f"unknown strategy {unknown}; choose from {', '.join(ALL_STRATEGIES)}")
    if trials < 1:
        raise ValueError("trials must be at least 1")

    if task not in TASK_NAMES:
        raise ValueError(f"unknown task {task!r}; choose from {', '.join(TASK_NAMES)}")
    have = query("SELECT DISTINCT take FROM episodes WHERE task = ? ORDER BY take", warehouse, [task]).column(0).to_pylist()
    use = [t for t in have if takes is None or t in takes]
    if not use:
        raise ValueError(f"no episode database for task {task!r}: run `demoforge augment` on a {task} take first")
    out = []
    for take in use:
        for strategy in strategies:
            m = run_stage(llm_trials, warehouse, task=task, take=take, strategy=strategy, warehouse=warehouse,
                          backend=backend, backend_options=backend_options or {}, trials=trials, seed=seed,
                          n_waypoints=n_waypoints, precision=precision, max_tokens=max_tokens,
                          structured=structured, number_format=number_format,
                          keyframes=keyframe_key(task, n_waypoints) if strategy in LLM_STRATEGIES else None)
            logger.info("%s %s %s: %d trials", task, take, strategy, m.rows)
            out.append(m)
    return out
