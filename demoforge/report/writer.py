"""Write reports/: REPORT.md (read top to bottom), one CSV per report view, PNG figures.

The sections are demoforge.schemas.reports.REPORT, in report order: this module renders each kind of
declaration (a view's table, a figure section, a table per dataset) and fills in the run's provenance
lines; it holds no section's prose."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv

from demoforge.lib.evaluation.markdown import markdown_table
from demoforge.report.figures import FIGURES, dataset_detectors
from demoforge.report.reader import ViewReader
from demoforge.runtime.provenance import git_commit
from demoforge.schemas.catalog import build_catalog
from demoforge.schemas.report_section import OMIT, FigureSection, PerDataset, ReportEntry, ReportSection
from demoforge.schemas.reports import REPORT, REPORT_VIEWS

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def stamps(params: dict, commit: str) -> dict[str, str]:
    """The provenance line of each stamp a section can name (demoforge.schemas.report_section.STAMPS);
    ``dataset`` is a template for a PerDataset's ``label`` and ``detectors``."""
    synthetic = (f"data: synthetic (demoforge.synth, MuJoCo renders, exact ground truth) · "
                 f"seeds {params.get('seed')}..{params.get('seed', 0) + params.get('takes', 1) - 1} · commit {commit}")
    detectors = ", ".join(params.get("detectors") or ["simulated"])
    llm = synthetic + f" · LLM backend: {params.get('llm_backend')} · trials per strategy: {params.get('trials')}"
    return {
        "synthetic": synthetic,
        "detectors": synthetic.replace("exact ground truth", f"exact ground truth; detectors: {detectors}"),
        "table3": llm + f" · LLM-free and policy scenes: {params.get('grid_scenes')}",
        "policy": synthetic + (f" · policy: {params.get('policy_epochs')} epochs, {params.get('policy_waypoints')} "
                               f"waypoints, {params.get('policy_trials')} scenes per kind"),
        "variations": synthetic + f" · scenes per task and variation: {params.get('variation_trials')}",
        "robots": synthetic + (f" · robots: {', '.join(params.get('robots') or ['grippers'])} · episodes per task: "
                               f"{params.get('sim_episodes')}"),
        "real_photos": f"data: real photos (../shared/data/real_hands) · commit {commit}",
        "dataset": "data: {label} · detectors: {detectors} · commit " + commit,
        "machine": "measured on this machine",
    }


def table_section(title: str, view: str, name: str, t: pa.Table, stamp: str, intro: str, reports: Path) -> str:
    """``## title``, the intro, the provenance line and ``t`` as a Markdown table; ``t`` also as ``<name>.csv``."""
    pacsv.write_csv(t, reports / f"{name}.csv")
    parts = [f"## {title}", ""]
    if intro:
        parts += [intro, ""]
    parts += [f"_{stamp} · SQL view `{view}` · CSV `{name}.csv`_", "",
              markdown_table(t.column_names, [list(r.values()) for r in t.to_pylist()])]
    return "\n".join(parts)


def section_lines(s: ReportSection, reader: ViewReader, reports: Path, lines: dict[str, str]) -> list[str]:
    """One view's section: its table (or what stands in for it when the view is empty), then its figure."""
    t = reader.view(s.view)
    if t.num_rows == 0 and s.if_empty is not None:
        return [] if s.if_empty == OMIT else [f"## {s.empty_title or s.title}", "", s.if_empty, ""]
    md = [table_section(s.title, s.view, s.view, t, lines[s.stamp], s.intro, reports)]
    if s.figure:
        md += [""] + FIGURES[s.figure](reader, reports)
    return md


def per_dataset_lines(group: PerDataset, reader: ViewReader, reports: Path, lines: dict[str, str]) -> list[str]:
    """The group's sections once per dataset of its table, each with that dataset's rows (the simulated
    detector first), then the dataset's figure."""
    md: list[str] = []
    order = "ORDER BY CASE detector WHEN 'simulated' THEN 0 ELSE 1 END, detector"
    for dataset in sorted({r["dataset"] for r in reader.view(group.table).to_pylist()}):
        stamp = lines["dataset"].format(label=group.labels.get(dataset, dataset),
                                        detectors=", ".join(dataset_detectors(reader, dataset)))
        for s in group.sections:
            t = reader.query(f"SELECT * FROM (SELECT *, row_number() OVER () AS _row FROM {s.view}) "
                             f"WHERE dataset = ? {order}, _row", [dataset]).drop_columns(["_row"])
            md.append(table_section(f"{s.title} — {dataset}, by detector", s.view, f"{s.view}_{dataset}", t, stamp,
                                    s.intro, reports))
        if group.figure:
            md += FIGURES[group.figure](reader, reports, dataset=dataset)
    return md


def entry_lines(entry: ReportEntry, reader: ViewReader, reports: Path, lines: dict[str, str]) -> list[str]:
    if isinstance(entry, PerDataset):
        return per_dataset_lines(entry, reader, reports, lines)
    if isinstance(entry, FigureSection):
        return [f"## {entry.title}", ""] + ([entry.intro, ""] if entry.intro else []) + FIGURES[entry.figure](
            reader, reports)
    return section_lines(entry, reader, reports, lines)


def write_report(warehouse: str | Path, reports_dir: str | Path, params: dict) -> Path:
    """reports_dir/REPORT.md with every section of demoforge.schemas.reports.REPORT in order, their CSVs
    and figures; inside a flow run also the Prefect artifacts. Returns the report's path."""
    reports = Path(reports_dir)
    reports.mkdir(parents=True, exist_ok=True)
    build_catalog(warehouse)
    reader = ViewReader(warehouse)  # this run's reads: each view once
    commit = git_commit(str(PROJECT_ROOT))
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    md = [
        "# demoforge report",
        "",
        f"Generated {now} by `make evaluate` (commit `{commit}`). Parameters: `{json.dumps(params, sort_keys=True)}`.",
        "Every table below is a DuckDB view in `warehouse/catalog.duckdb`: run "
        "`demoforge sql \"SELECT * FROM <view>\"` to query it yourself.",
        "",
    ]
    lines = stamps(params, commit)
    for entry in REPORT:
        md += entry_lines(entry, reader, reports, lines)
    out = reports / "REPORT.md"
    tmp = out.with_name(".REPORT.md.tmp")
    tmp.write_text("\n".join(md))
    tmp.replace(out)
    publish_artifacts(reader, out, sorted(REPORT_VIEWS))
    return out


def publish_artifacts(reader: ViewReader, report: Path, views: list[str], max_rows: int = 200) -> int:
    """Inside a flow run: the report as a Markdown artifact and every non-empty report view as a table
    artifact, so the Prefect UI shows the results of the run. Returns how many were published."""
    from prefect.artifacts import create_markdown_artifact, create_table_artifact
    from prefect.context import FlowRunContext

    if FlowRunContext.get() is None:
        return 0
    text = report.read_text()
    create_markdown_artifact(text, key="demoforge-report", description=f"{report} (figures in {report.parent})")
    n = 1
    for name in views:
        t = reader.view(name)
        if t.num_rows == 0:
            continue
        rows = [{k: (round(v, 6) if isinstance(v, float) else v if isinstance(v, (int, str, bool)) or v is None
                     else str(v)) for k, v in r.items()} for r in t.slice(0, max_rows).to_pylist()]
        create_table_artifact(rows, key=name.replace("_", "-"),
                              description=f"SQL view `{name}` ({t.num_rows} rows; `demoforge sql \"SELECT * FROM {name}\"`)")
        n += 1
    return n
