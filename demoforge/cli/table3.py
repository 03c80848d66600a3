"""`demoforge table3`: the thesis's Table 3 grid (a sub-app composed into the root app)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from demoforge.cli.root import (TASK_HELP, api_mode_option, base_url_option, current_warehouse, fail, gripper_option,
                                llm_backend_option, llm_backend_options, number_format_option, robot_option,
                                robot_spec, structured_option, waypoints_option)
from demoforge.runtime.runners import run_flow

app = typer.Typer()


@app.command("table3")
def table3_cmd(
    task: str = typer.Option("pouring", "--task", "-t", help="Task of the grid (the thesis: pouring). " + TASK_HELP),
    protocol: Optional[List[str]] = typer.Option(None, "--protocol", "-p", help="thesis (default: query scenes from each take's own augmentation sampler, held-out seeds) or novel (the task library's independent placements with yaw, against a database built to cover them). Repeatable."),
    takes: int = typer.Option(5, min=1, help="Synthetic takes (seeds seed, seed+1, ...), each with its own database."),
    take_dir: Optional[List[Path]] = typer.Option(None, "--take-dir", exists=True, file_okay=False, help="Take folders to build the databases from instead of synthetic takes (your own recordings, annotated; repeatable; --takes is then their count)."),
    scenes: int = typer.Option(10, min=1, help="Query scenes per take (the thesis: 10)."),
    llm_scenes: Optional[int] = typer.Option(None, min=0, help="Scenes of the three LLM strategies (default: all `scenes`; a trial of the local model takes 14-50 s on 2 cores, by CPU, examples and number format)."),
    strategy: Optional[List[str]] = typer.Option(None, "--strategy", "-s", help="single, random, retrieval (the LLM prompts), replay_original, replay_top1, knn_blend, transform_demo (LLM-free), policy (repeatable; default all)."),
    backend: str = llm_backend_option(),
    model: Optional[str] = typer.Option(None, envvar="DEMOFORGE_LLM_MODEL", help="Model name for the openai backend."),
    seed: int = typer.Option(0, help="Seed of the takes, databases, query scenes, random examples and policy."),
    episodes: int = typer.Option(10_000, "--episodes", "-n", min=10, help="Episodes per database (the thesis: 10,000)."),
    policy_epochs: int = typer.Option(6, min=1, help="Training epochs of the policy column (the same as `make evaluate`'s, so its checkpoint is shared)."),
    waypoints: Optional[int] = waypoints_option(),
    structured: Optional[bool] = structured_option(),
    base_url: Optional[str] = base_url_option(),
    api_mode: str = api_mode_option(),
    number_format: Optional[str] = number_format_option(),
    robot: str = robot_option(),
    gripper: Optional[str] = gripper_option(),
) -> None:
    """Run the thesis's Table 3 grid: takes x query scenes x strategies, judged in MuJoCo.

    Prints Table 3 in the thesis's layout (Take1..TakeN and the average; One Demo / 3 Random /
    3 Retrieved, then the LLM-free baselines and the learned policy), the Wilson 95 % intervals and the
    failure reasons, per protocol. Every cell is cached: an interrupted grid resumes where it stopped.
    """
    from demoforge.flows.table3 import table3  # lazy: prefect
    # lazy (CLI start-up): duckdb, pyarrow
    from demoforge.lib.evaluation.markdown import markdown_table
    from demoforge.schemas.catalog import query
    from demoforge.tasks.table3 import ALL_STRATEGIES  # lazy: prefect

    from demoforge.lib.trajectories.query_scenes import PROTOCOLS  # lazy (CLI start-up): numpy, scipy

    protocols = protocol or ["thesis"]
    bad = [p for p in protocols if p not in PROTOCOLS] + [s for s in strategy or [] if s not in ALL_STRATEGIES]
    if bad:
        raise fail(f"unknown protocol or strategy {bad}: protocols {', '.join(PROTOCOLS)}; "
                   f"strategies {', '.join(ALL_STRATEGIES)}")
    if llm_scenes is not None and llm_scenes > scenes:
        raise fail(f"--llm-scenes ({llm_scenes}) cannot exceed --scenes ({scenes})")
    spec = robot_spec(robot, gripper)
    robot, gripper = spec.robot, spec.gripper
    try:
        run_flow(table3, str(current_warehouse()), task=task, protocols=protocols, scenes=scenes,
                 takes=len(take_dir) if take_dir else takes, take_dirs=[str(p) for p in take_dir] if take_dir else None,
                 llm_scenes=llm_scenes, strategies=strategy or list(ALL_STRATEGIES), backend=backend,
                 backend_options=llm_backend_options(backend, model, base_url, api_mode), seed=seed, episodes=episodes,
                 policy_epochs=policy_epochs, n_waypoints=waypoints, structured=structured,
                 number_format=number_format, robot=spec)
    except ValueError as e:
        raise fail(str(e))
    where = "WHERE task = ? AND list_contains(?, protocol) AND robot = ? AND gripper = ?"
    for title, view in (("Table 3", "report_table3_grid"), ("Wilson 95 % intervals", "report_table3_intervals"),
                        ("Outcomes", "report_table3_failures")):
        t = query(f"SELECT * EXCLUDE (robot, gripper) FROM {view} {where}", current_warehouse(),
                  [task, list(protocols), robot, gripper])
        typer.echo(f"\n{title}\n\n" + markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()]))
