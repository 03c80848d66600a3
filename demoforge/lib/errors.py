"""Which errors are the user's (bad input, a missing file, an unknown option) and which are crashes.

A user error is reported as one line (``error: <message>``, exit code 2) with no traceback: its
message names the file or option and the fix. Everything else is a crash of demoforge and keeps its
traceback. The rule, in one place so the CLI and the Prefect log filter agree:

- :class:`UserError` and its subclasses (``TakeError``, ``QueryRefused``, ``ExportError``, the
  HaMeR checkpoint/MANO errors, :class:`UnknownNameError`: an unknown robot, hand, task, take source,
  hand detector or LLM backend) are user errors (``SchemaError`` is not: a stage writing rows that
  break its table's contract is a bug);
- so are the failures of what the user pointed demoforge at: an LLM backend (``LLMError``: a dead,
  slow or failing server, a missing model), a detector that cannot run (``DetectorError``) and a
  missing ARCTIC download (``ArcticError``);
- and a plain ``ValueError`` raised by a ``raise`` statement in ``flows/`` or ``tasks/``: that code
  only orchestrates, its ValueErrors are its argument checks (an unknown task, no episode database
  yet). A ValueError raised deeper (numpy, pyarrow, a lib/ invariant) is a crash.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
_ORCHESTRATION_DIRS = tuple(str(PACKAGE_ROOT / d) + "/" for d in ("flows", "tasks"))
# RuntimeError-based error classes of lib/ that are about the user's environment, by module and name
# (imported lazily: demoforge.lib.llm and demoforge.lib.perception.detectors pull in heavy modules).
_ENVIRONMENT_ERRORS = (("demoforge.lib.llm", "LLMError"), ("demoforge.lib.perception.detectors", "DetectorError"), ("demoforge.lib.evaluation.arctic", "ArcticError"))


class Reporting:
    """How user errors are shown in this process, set by the CLI (`demoforge --debug`): whether the
    console leaves them to the CLI's one line, and whether tracebacks are shown anyway. Read by the
    Prefect log filter of tasks/common.py when it is installed (Prefect is imported only by commands
    that run flows)."""

    cli_reports = False
    show_tracebacks = False
    #: The ``warning: ...`` lines this command printed: a warning found by a stage and repeated by
    #: the command's own summary is printed once.
    warnings_shown: set[str] = set()

    @classmethod
    def first_time(cls, line: str) -> bool:
        """True the first time ``line`` is about to be printed (and remember it)."""
        if line in cls.warnings_shown:
            return False
        cls.warnings_shown.add(line)
        return True


class UserError(ValueError):
    """Bad input or options: the message says which file or option and how to fix it."""


class UnknownNameError(UserError):
    """A name that a registry (demoforge.lib.registry: robots, hands, take sources, hand detectors, LLM
    backends) does not know; the one-line message lists the names it does. ``kind``, ``name`` and
    ``choices`` say the same for a caller that words it another way (the CLI names its option)."""

    def __init__(self, message: str, *, kind: str = "", name: str = "", choices: tuple[str, ...] = ()):
        super().__init__(message)
        self.kind, self.name, self.choices = kind, name, tuple(choices)

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class UnknownTaskError(UnknownNameError, KeyError):
    """A task name the library does not know (a user's `--task` typo: one line, exit 2)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


def _environment_error_types() -> tuple[type, ...]:
    import sys

    found = []
    for module, name in _ENVIRONMENT_ERRORS:
        mod = sys.modules.get(module)  # not imported yet: nothing can have raised it
        if mod is not None and isinstance(getattr(mod, name, None), type):
            found.append(getattr(mod, name))
    return tuple(found)


def is_user_error(exc: BaseException | None) -> bool:
    """True when ``exc`` is the user's to fix (see the module docstring), False for a crash."""
    if exc is None:
        return False
    if isinstance(exc, UserError) or isinstance(exc, _environment_error_types()):
        return True
    if type(exc) is ValueError:
        tb = exc.__traceback__
        if tb is None:
            return False
        while tb.tb_next is not None:
            tb = tb.tb_next
        return tb.tb_frame.f_code.co_filename.startswith(_ORCHESTRATION_DIRS)
    return False


def one_line(exc: BaseException, limit: int = 600) -> str:
    """The exception's message on one line (long messages cut)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def release_frames(error: BaseException | None) -> None:
    """Let go of what a reported error holds: the local variables of the finished frames it passed
    through, and the errors it came from (``__cause__``/``__context__``, already shown or suppressed).

    Prefect keeps a failed run's error in its state until the process ends, and with it everything
    those hold; a DuckDB error (or connection) still alive when the interpreter tears its modules down
    makes nanobind print dozens of "leaked instance" lines after the one-line error. The error's own
    traceback (files and lines) stays; with ``--debug`` (``Reporting.show_tracebacks``) nothing is
    released, so the full chain is printed."""
    import traceback

    if Reporting.show_tracebacks or error is None:
        return
    chain: list[BaseException] = []
    while error is not None and all(error is not seen for seen in chain):
        chain.append(error)
        error = error.__cause__ or error.__context__
    for i, err in enumerate(chain):
        traceback.clear_frames(err.__traceback__)
        if i:
            err.__traceback__ = None
        err.__cause__ = err.__context__ = None
