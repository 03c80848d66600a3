"""What a section of reports/REPORT.md is, as data: the report writer (demoforge.report) reads these
declarations in report order and has no prose of its own.

A :class:`ReportSection` is one table of the report: its title, the DuckDB view it shows with that view's
SQL, an intro, the tables the view is computed from, which provenance line it carries, what stands in its
place when the view is empty and a figure drawn after it. Each is declared next to its view's SQL (in
schemas/reports.py, or beside its table's contract); schemas/reports.py collects them all, in report
order, into ``REPORT`` and the catalog's views. A :class:`SqlView` is a report view for SQL only (the
report does not show it); a :class:`FigureSection` is a section of figures without a view; a
:class:`PerDataset` repeats its sections once per dataset of a table.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The provenance line under a section's title (the report writer fills each in from the run's parameters).
STAMPS = {
    "synthetic": "the synthetic takes: seeds and commit",
    "detectors": "the synthetic takes and the hand detectors run on them",
    "table3": "the synthetic takes, the LLM backend, trials per strategy and the LLM-free scenes",
    "policy": "the synthetic takes and the learned policy's epochs, waypoints and scenes",
    "variations": "the synthetic takes and the scenes per task and variation",
    "robots": "the synthetic takes, the robots and the episodes per task",
    "real_photos": "the labelled real photos",
    "dataset": "a PerDataset's dataset (its label) and the detectors run on it",
    "machine": "the machine the benchmarks ran on",
}

#: The figures a section can draw (the report writer draws each).
FIGURES = {
    "synthetic_takes": "one rendered frame per task with its ground-truth skeletons and object keypoints",
    "keypoints": "per detector of a dataset: aligned MPJPE per take, and big vs small objects",
    "data_scaling": "closed-loop success against training episodes",
    "episode_databases": "per task: trajectories, workspace coverage, a success map per robot",
}

#: ``if_empty`` of a section that the report leaves out when its view has no rows.
OMIT = ""


def _check_keys(what: str, stamp: str | None, figure: str | None) -> None:
    if stamp is not None and stamp not in STAMPS:
        raise ValueError(f"{what}: unknown stamp {stamp!r}; one of {', '.join(STAMPS)}")
    if figure is not None and figure not in FIGURES:
        raise ValueError(f"{what}: unknown figure {figure!r}; one of {', '.join(FIGURES)}")


@dataclass(frozen=True)
class ReportSection:
    """One table of the report: ``## title``, the intro, the provenance line, the view as a Markdown table
    (and as ``<view>.csv``), then the figure if any.

    computed_from: the tables (and table views, e.g. ``sim_outcomes``) the SQL reads. if_empty: when the
    view has no rows, None shows the empty table, :data:`OMIT` leaves the section out, any other text is
    shown under ``empty_title`` (default: the title) instead of the table."""

    view: str
    title: str
    sql: str
    computed_from: tuple[str, ...]
    intro: str = ""
    stamp: str = "synthetic"
    if_empty: str | None = None
    empty_title: str | None = None
    figure: str | None = None

    def __post_init__(self) -> None:
        if not self.view.startswith("report_"):
            raise ValueError(f"report view {self.view!r}: its name must start with report_")
        _check_keys(self.view, self.stamp, self.figure)


@dataclass(frozen=True)
class SqlView:
    """A report view for SQL only (`demoforge sql`): the report does not show it, ``why`` says why."""

    view: str
    sql: str
    computed_from: tuple[str, ...]
    why: str


@dataclass(frozen=True)
class FigureSection:
    """A section of figures without a view of its own: ``## title``, the intro, the figure."""

    title: str
    figure: str
    intro: str = ""

    def __post_init__(self) -> None:
        _check_keys(self.title, None, self.figure)


@dataclass(frozen=True)
class PerDataset:
    """``sections`` once per dataset found in ``table`` (its column ``dataset``), each view's rows of that
    dataset under ``## <title> — <dataset>, by detector``, then the dataset's figure. ``labels`` names
    each dataset's data in the provenance line."""

    table: str
    sections: tuple[ReportSection, ...]
    labels: dict[str, str]
    figure: str | None = None

    def __post_init__(self) -> None:
        _check_keys(self.table, None, self.figure)


ReportEntry = ReportSection | FigureSection | PerDataset
