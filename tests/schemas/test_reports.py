"""The report's sections as data (demoforge.schemas.reports): every report view is a section of the report or
declared for SQL only, each declaration names what it is computed from and what the writer knows how to
draw, and the writer shows them in report order (demoforge.report)."""

import re

import duckdb

from demoforge.report.figures import FIGURES
from demoforge.report.reader import ViewReader
from demoforge.report.writer import stamps, write_report
from demoforge.schemas import registry
from demoforge.schemas.catalog import CATALOG_FILE, build_catalog
from demoforge.schemas.report_section import FIGURES as DECLARED_FIGURES
from demoforge.schemas.report_section import OMIT, STAMPS, FigureSection, PerDataset
from demoforge.schemas.reports import REPORT, REPORT_VIEWS, SHOWN_VIEWS, SQL_ONLY, TABLE_VIEWS, shown_sections


def test_every_report_view_of_the_catalog_is_a_section_or_declared_sql_only(tmp_path):
    build_catalog(tmp_path)
    con = duckdb.connect(str(tmp_path / CATALOG_FILE), read_only=True)
    try:
        views = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
    finally:
        con.close()
    report_views = {v for v in views if v.startswith("report_")}
    sql_only = {v.view for v in SQL_ONLY}
    assert report_views - SHOWN_VIEWS - sql_only == set(), "report views with no section, not declared SQL-only"
    assert SHOWN_VIEWS | sql_only == report_views == set(REPORT_VIEWS)
    assert not SHOWN_VIEWS & sql_only


def test_declarations_name_real_tables_and_what_the_writer_draws():
    declared = [*shown_sections(), *SQL_ONLY]
    assert len({d.view for d in declared}) == len(declared)
    known = set(registry()) | set(TABLE_VIEWS)
    for d in declared:
        assert d.computed_from and set(d.computed_from) <= known, d.view
        for name in d.computed_from:  # what it is computed from is what its SQL reads
            assert re.search(rf"\b{name}\b", d.sql), (d.view, name)
    assert set(stamps({}, "abc")) == set(STAMPS)
    assert set(FIGURES) == set(DECLARED_FIGURES)
    used = {s.stamp for s in shown_sections()}
    assert used <= set(STAMPS)
    titles = [s.title for s in shown_sections()] + [e.title for e in REPORT if isinstance(e, FigureSection)]
    assert len(set(titles)) == len(titles)


def test_the_reader_queries_each_view_once_per_run(tmp_path):
    build_catalog(tmp_path)
    reader = ViewReader(tmp_path)
    assert reader.view("report_takes") is reader.view("report_takes")
    assert ViewReader(tmp_path).view("report_takes") is not reader.view("report_takes")  # nothing kept between runs


def test_an_empty_warehouse_gives_every_section_in_report_order(tmp_path):
    params = {"seed": 0, "takes": 1}
    out = write_report(tmp_path / "warehouse", tmp_path / "reports", params)
    text = out.read_text()
    expected = []  # (heading, what follows it) in report order
    for e in REPORT:
        if isinstance(e, FigureSection):
            expected.append(f"## {e.title}")
        elif isinstance(e, PerDataset):
            continue  # once per dataset: none in an empty warehouse
        elif e.if_empty is None:
            expected.append(f"## {e.title}")
            assert f"SQL view `{e.view}` · CSV `{e.view}.csv`" in text
            assert (tmp_path / "reports" / f"{e.view}.csv").is_file()
        elif e.if_empty == OMIT:
            assert f"## {e.title}" not in text
        else:
            expected.append(f"## {e.empty_title or e.title}")
            assert e.if_empty in text
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings == expected
    assert "_No episodes in this warehouse yet" in text and "_(no take to show)_" in text
