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

from demoforge.lib.errors import Reporting, is_user_error, one_line, release_frames
from demoforge.lib.settings import adopt_old_names
from demoforge.runtime import runners


# Click's own exits and usage errors (typer vendors click: both its copy's classes and click's)
_tclick = getattr(typer.core, "_click", click)
_CLICK_OWN = (typer.Exit, typer.Abort, click.exceptions.Exit, click.exceptions.Abort, click.ClickException,
              _tclick.ClickException)


class _ErrorsAtTheBoundary(TyperGroup):
    """Every command's errors end here: a user error (demoforge.lib.errors) is one line on stderr and exit code 2,
    whichever command or flow raised it; a crash is a short summary with the hint to rerun with
    --debug (exit code 1); with --debug both keep their full traceback."""

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name, command, rest = super().resolve_command(ctx, args)
        if command is not None and any(a in ctx.help_option_names for a in rest):
            list_choices(command)  # the registries' names, in the help about to be shown
        return name, command, rest

    def invoke(self, ctx: click.Context):
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
    from demoforge.schemas.catalog import warehouse_root  # lazy (CLI start-up): duckdb, pyarrow

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
    from demoforge.lib.llm.number_format import NUMBER_FORMATS  # lazy (CLI start-up): numpy

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


# The choices an option's --help lists, from the registries themselves: a `{token}` in an option's help is
# replaced when that help is shown (_ErrorsAtTheBoundary.resolve_command), so a plain run of a command never
# loads the detectors, the robots' models or the task library just to word its help.
def _hands_text() -> str:
    from demoforge.lib.robot_spec import available_robots, gripper_choices  # lazy (CLI start-up)

    return "; ".join(f"{r}: {' or '.join(gripper_choices(r))}" for r in available_robots())


def _task_names() -> tuple[str, ...]:
    from demoforge.lib.task_names import TASK_NAMES  # lazy (CLI start-up)

    return tuple(TASK_NAMES)


def _detector_names() -> list[str]:
    from demoforge.lib.perception.detector_registry import available_detectors  # lazy (CLI start-up)

    return available_detectors()


def _backend_names() -> tuple[str, ...]:
    from demoforge.lib.llm import BACKENDS  # lazy (CLI start-up)

    return BACKENDS.names()


def _robot_names() -> tuple[str, ...]:
    from demoforge.lib.robot_spec import available_robots  # lazy (CLI start-up)

    return available_robots()


def _robot_labels() -> tuple[str, ...]:
    from demoforge.lib.robot_spec import robot_labels  # lazy (CLI start-up)

    return robot_labels()


CHOICES = {
    "{robots}": lambda: ", ".join(_robot_names()),
    "{robot_labels}": lambda: ", ".join(_robot_labels()),
    "{grippers}": _hands_text,
    "{detectors}": lambda: ", ".join(_detector_names()),
    "{llm_backends}": lambda: ", ".join(_backend_names()),
    "{tasks}": lambda: ", ".join(_task_names()),
}


def list_choices(command) -> None:
    """Replace the `{token}`s of CHOICES in the help of `command`'s options by the registered names."""
    for param in getattr(command, "params", ()):
        text = getattr(param, "help", None)
        if text and "{" in text:
            for token, names in CHOICES.items():
                if token in text:
                    text = text.replace(token, names())
            param.help = text


def check_choice(option: str, value: str, names) -> str:
    """`value` if it is one of `names`, else the one-line error naming the option and the choices (exit 2)."""
    names = tuple(names)
    if value not in names:
        raise fail(f"{option} must be one of {', '.join(names)}, got {value!r}")
    return value


def _check_detector(value):
    for v in ([] if value is None else [value] if isinstance(value, str) else value):
        check_choice("--detector", v, _detector_names())
    return value


def _check_backend(value: str | None) -> str | None:
    if value is not None:
        check_choice("--backend", value.strip().lower(), _backend_names())
    return value


TASK_HELP = "One of: {tasks}."


def detector_option(default: str | None = "simulated", help: str = ""):
    """--detector/-d: a hand detector of the registry (demoforge.lib.perception.detectors), checked while parsing."""
    return typer.Option(default, "--detector", "-d", callback=_check_detector,
                        help=(help + " " if help else "") + "One of: {detectors}.")


def llm_backend_option(flag: str = "--backend", help: str = ""):
    """The LLM backend (demoforge.lib.llm.BACKENDS), checked while parsing; $DEMOFORGE_LLM_BACKEND."""
    return typer.Option("local", flag, envvar="DEMOFORGE_LLM_BACKEND", callback=_check_backend,
                        help="One of: {llm_backends}. " + (help or "local: Gemma 3 270M via llama.cpp, offline; openai: "
                                                           "OPENAI_BASE_URL, OPENAI_API_KEY, DEMOFORGE_LLM_MODEL; fake: "
                                                           "scripted answers, for tests."))


# The robot options of every command that runs a robot (simulate, stability, render-episode, table3,
# export): declared once; robot_spec() turns them into the one demoforge.lib.robot_spec.RobotSpec the
# command passes down.
ROBOT_HELP = ("The robot that executes the episodes, one of: {robots}. grippers: two free-floating Robotiq "
              "2F-140-class grippers following the poses (every pose is reachable); aloha: two ViperX 300 6-DOF arms "
              "driven in joint space through inverse kinematics (unreachable poses, joint limits and arm-link "
              "collisions fail).")
GRIPPER_HELP = ("The robot's hands ({grippers}; default: the robot's own, the first). ALOHA's own fingers (aloha) "
                "have 69 mm between the pads: the bottle (70 mm), cup, container and vase are wider; 2f140 is the "
                "Robotiq 2F-140, opening 110 mm.")


def robot_option(envvar: str | None = None, default: str = "grippers", help: str = ROBOT_HELP):
    return typer.Option(default, "--robot", envvar=envvar, help=help)


def gripper_option(envvar: str | None = None, default: str | None = None):
    return typer.Option(default, "--gripper", envvar=envvar, help=GRIPPER_HELP)


def robot_spec(robot: str, gripper: str | None):
    """The RobotSpec of --robot and --gripper, checked here once (one line naming the choices, exit 2)."""
    from demoforge.lib.robot_spec import RobotError, RobotSpec  # lazy (CLI start-up)

    try:
        return RobotSpec.from_options(robot, gripper)
    except RobotError as e:
        if e.kind == "robot":
            raise fail(f"--robot must be one of {', '.join(e.choices)}, got {robot!r}")
        raise fail(f"--gripper {gripper!r}: the {robot} robot carries {' or '.join(e.choices)}")


def robot_choice(robot: str, gripper: str | None) -> tuple[str, str]:
    """(robot, hand) of robot_spec: for the commands that pass them on as two strings."""
    spec = robot_spec(robot, gripper)
    return spec.robot, spec.gripper
