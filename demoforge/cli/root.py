"""The root `demoforge` command: global options, the error boundary (one line for a user's
mistake, a short summary for a crash), the warehouse in use."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Optional
import click
import typer
from typer.core import TyperGroup

import demoforge.lib  # noqa: F401  (sets MUJOCO_GL before anything imports mujoco)


# Click's own exits and usage errors (typer vendors click: both its copy's classes and click's)
_tclick = getattr(typer.core, "_click", click)
_CLICK_OWN = (typer.Exit, typer.Abort, click.exceptions.Exit, click.exceptions.Abort, click.ClickException,
              _tclick.ClickException)


class _ErrorsAtTheBoundary(TyperGroup):
    """Every command's errors end here: a user error (demoforge.lib.errors) is one line on stderr and exit code 2,
    whichever command or flow raised it; a crash is a short summary with the hint to rerun with
    --debug (exit code 1); with --debug both keep their full traceback."""

    def invoke(self, ctx: click.Context):
        from demoforge.lib.errors import is_user_error, one_line, release_frames

        try:
            return super().invoke(ctx)
        except _CLICK_OWN:
            raise
        except BrokenPipeError:
            raise  # the reader of stdout went away (`| head`): Typer ends quietly, as Unix tools do
        except Exception as e:
            if State.debug:
                raise
            import traceback

            where = traceback.extract_tb(e.__traceback__)[-1]
            release_frames(e)
            if is_user_error(e):
                raise fail(one_line(e))
            typer.echo(f"error: demoforge crashed: {type(e).__name__}: {one_line(e, 300)} "
                       f"(at {where.filename}:{where.lineno}); this is a bug, not your input: rerun with "
                       f"--debug (demoforge --debug COMMAND ...) for the full traceback and report it", err=True)
            raise typer.Exit(1)



app = typer.Typer(
    cls=_ErrorsAtTheBoundary,
    name="demoforge",
    help=(
        "Turn one RGB-D video of a two-handed human demonstration into thousands of dual-arm robot "
        "episodes, and measure how good they are. All results are Parquet tables in the warehouse "
        "(default ./warehouse, or $DEMOFORGE_WAREHOUSE, or --warehouse), queryable with `demoforge sql`."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

EXIT_USER_ERROR = 2


def warn(message: str) -> None:
    """Print ``warning: MESSAGE`` to stderr, unless a stage of this command already printed it."""
    from demoforge.lib.errors import Reporting

    line = f"warning: {message}"
    if Reporting.first_time(line):
        typer.echo(line, err=True)


def fail(message: str) -> "typer.Exit":
    """Print a one-line error to stderr and return the exit to raise (code 2)."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(EXIT_USER_ERROR)


class State:
    warehouse: Optional[Path] = None
    debug: bool = False


def current_warehouse() -> Path:
    from demoforge.schemas.catalog import warehouse_root

    return warehouse_root(State.warehouse)


@app.callback()
def _main(
    warehouse: Optional[Path] = typer.Option(
        None, "--warehouse", "-w", envvar="DEMOFORGE_WAREHOUSE",
        help="Warehouse folder (Parquet tables + catalog.duckdb). Default: ./warehouse of the project.",
    ),
    task_runner: Optional[str] = typer.Option(
        None, "--task-runner", envvar="DEMOFORGE_TASK_RUNNER",
        help="Where tasks run: threads (default, this process) or dask (a Dask cluster, see --dask-address).",
    ),
    dask_address: Optional[str] = typer.Option(
        None, "--dask-address", envvar="DEMOFORGE_DASK_ADDRESS",
        help="Scheduler of an existing Dask cluster (tcp://host:8786); without it, --task-runner dask starts "
             "a local cluster of $DEMOFORGE_DASK_WORKERS (default 2) worker processes.",
    ),
    debug: bool = typer.Option(
        False, "--debug", envvar="DEMOFORGE_DEBUG",
        help="Show full tracebacks: of crashes, and of user errors too (normally one line, exit code 2).",
    ),
) -> None:
    from demoforge.runtime import runners
    from demoforge.lib.errors import Reporting
    from demoforge.lib.settings import adopt_old_names

    # before the command's own options are parsed (click parses them after this callback), so an old
    # unprefixed name still reaches the option it used to set
    adopt_old_names()

    State.warehouse = warehouse
    State.debug = debug
    Reporting.cli_reports, Reporting.show_tracebacks = True, debug
    Reporting.warnings_shown.clear()  # per command (tests run several in one process)
    if "demoforge.tasks.common" in sys.modules:  # else its import installs the filters (Prefect only when needed)
        sys.modules["demoforge.tasks.common"].quiet_user_errors()
    runners.install_interrupt_handler()
    if task_runner:
        os.environ[runners.ENV_RUNNER] = task_runner
    if dask_address:
        os.environ[runners.ENV_ADDRESS] = dask_address
    try:
        kind = runners.runner_kind()
        if kind == "dask" and not dask_address:
            runners.dask_workers()
    except ValueError as e:
        raise fail(str(e))


def llm_backend_options(backend: str, model: str | None, base_url: str | None, api_mode: str) -> dict:
    """The openai backend's constructor options from the llm commands' flags (the local backend takes none)."""
    if api_mode not in ("chat", "completions"):
        raise fail(f"--api-mode must be chat or completions, got {api_mode!r}")
    if backend.strip().lower() != "openai":
        return {}
    options: dict = {"mode": api_mode}
    if model:
        options["model"] = model
    if base_url:
        options["base_url"] = base_url
    return options


def _check_number_format(name: str | None) -> str | None:
    """--number-format names one of demoforge.lib.llm.number_format's formats (else a one-line error)."""
    from demoforge.lib.llm.number_format import NUMBER_FORMATS

    if name is not None and name not in NUMBER_FORMATS:
        raise fail(f"--number-format must be one of {', '.join(NUMBER_FORMATS)}, got {name!r}")
    return name


# The LLM commands' shared options (llm-eval, table3; evaluate the first two): declared once, the number
# format checked while parsing.
def structured_option():
    return typer.Option(None, "--structured/--free", envvar="DEMOFORGE_LLM_STRUCTURED", help="Constrain the answer to the action-list syntax with the expected waypoint count (local: a llama.cpp grammar; openai: a JSON schema in chat mode, a `grammar` field in completions mode). Default: on for local, off for openai.")


def number_format_option():
    return typer.Option(None, "--number-format", envvar="DEMOFORGE_LLM_NUMBER_FORMAT", callback=_check_number_format, help="How the prompt writes numbers: thesis (default: metres, Appendix A) or compact (positions in mm, quaternions x 100, as integers: about 40 % fewer tokens and about half the time per trial).")


def waypoints_option():
    return typer.Option(None, "--waypoints", min=2, help="How the prompts write each example's action sequence: by default its keyframes (the sequence smoothed, then the steps a linear / slerp reconstruction cannot do without, gripper open/close instants kept; the answer is decoded as the robot interpolates). N: every sequence resampled uniformly to N waypoints instead (the earlier prompts; at 20, most of a database's own successful episodes fail once resampled).")


def base_url_option():
    return typer.Option(None, "--base-url", help="OpenAI-compatible endpoint of the openai backend, e.g. http://127.0.0.1:8080/v1 (default: OPENAI_BASE_URL, else api.openai.com).")


def api_mode_option():
    return typer.Option("chat", "--api-mode", help="openai backend: chat (/chat/completions with the prompt's messages) or completions (/completions with the prompt text, for base models).")


# The robot options of every command that runs a robot (simulate, stability, render-episode, table3,
# evaluate, export): declared once, checked while parsing.
ROBOT_HELP = ("The robot that executes the episodes: grippers (two free-floating Robotiq 2F-140-class grippers "
              "following the poses: every pose is reachable) or aloha (two ViperX 300 6-DOF arms driven in joint "
              "space through inverse kinematics: unreachable poses, joint limits and arm-link collisions fail).")
GRIPPER_HELP = ("The hands of --robot aloha: aloha (ALOHA's own fingers, 69 mm between the pads: the bottle (70 mm), "
                "cup, container and vase are wider) or 2f140 (the Robotiq 2F-140 on the wrists, opening 110 mm). "
                "Default: the robot's own.")


def _check_robot(name: str) -> str:
    from demoforge.lib.sim.robots import available_robots

    if name not in available_robots():
        raise fail(f"--robot must be one of {', '.join(available_robots())}, got {name!r}")
    return name


def robot_option(envvar: str | None = None):
    return typer.Option("grippers", "--robot", envvar=envvar, callback=_check_robot, help=ROBOT_HELP)


def gripper_option(envvar: str | None = None):
    return typer.Option(None, "--gripper", envvar=envvar, help=GRIPPER_HELP)


def robot_choice(robot: str, gripper: str | None) -> tuple[str, str]:
    """(robot, hand) after checking that the robot carries that hand (one line naming the choices)."""
    from demoforge.lib.sim.robots import RobotError, gripper_choices

    try:
        choices = gripper_choices(robot)
    except RobotError as e:
        raise fail(str(e))
    if gripper is not None and gripper not in choices:
        raise fail(f"--gripper {gripper!r}: the {robot} robot carries {' or '.join(choices)}")
    return robot, gripper or choices[0]
