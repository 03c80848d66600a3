"""`demoforge`: the command line. Each command is a thin call into a flow or the catalog.

The root app (:mod:`demoforge.cli.root`: global options, the error boundary) composes one sub-app per
area with ``add_typer``; the areas import the root (and a few shared helpers of one another), never
this module, so there is no import cycle (tests/test_architecture.py).
"""

from __future__ import annotations

from demoforge.cli import warehouse
from demoforge.cli import benchmarks
from demoforge.cli import takes
from demoforge.cli import capture
from demoforge.cli import pipeline
from demoforge.cli import evaluation
from demoforge.cli import export
from demoforge.cli import hamer
from demoforge.cli import policy
from demoforge.cli import table3
from demoforge.cli import variations
from demoforge.cli import screening
from demoforge.cli.root import EXIT_USER_ERROR, State, app, current_warehouse, fail  # noqa: F401

for _area in (warehouse, benchmarks, takes, capture, pipeline, evaluation, export, hamer, policy, table3, variations,
              screening):
    app.add_typer(_area.app)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
