"""`demoforge sql`, `tables`, `catalog`: the warehouse's tables from the command line."""

from __future__ import annotations

import enum
import sys
from pathlib import Path
from typing import List, Optional
import typer

from demoforge.cli.root import current_warehouse, fail

app = typer.Typer()


class OutputFormat(str, enum.Enum):
    table = "table"
    csv = "csv"
    json = "json"
    parquet = "parquet"


@app.command()
def sql(
    query: str = typer.Argument(..., help='One read-only statement, e.g. "SELECT * FROM benchmarks LIMIT 5".'),
    format: OutputFormat = typer.Option(OutputFormat.table, "--format", "-f", help="Output format."),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="Write to this file instead of stdout (required for parquet)."),
    max_rows: int = typer.Option(40, help="Rows shown in `table` format (the rest are elided)."),
) -> None:
    """Run a read-only SQL query over the warehouse (DuckDB) and print or save the result.

    Every table is a view in warehouse/catalog.duckdb; `demoforge tables` lists them with their
    columns. Statements that would write (INSERT, DROP, COPY, ...) are refused with exit code 2, and
    so are reads of anything but the warehouse's tables (read_text, read_csv, ATTACH, URLs, ...).
    """
    from demoforge.schemas.catalog import QueryRefused, query as run_query  # lazy (CLI start-up): duckdb, pyarrow

    try:
        result = run_query(query, current_warehouse())
    except QueryRefused as e:
        raise fail(str(e))
    _emit(result, format, output, max_rows)


def _emit(result, fmt: OutputFormat, output: Optional[Path], max_rows: int) -> None:
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    if fmt is OutputFormat.parquet:
        if output is None:
            raise fail("--format parquet needs --output FILE")
        pq.write_table(result, output)
        typer.echo(f"wrote {result.num_rows} rows to {output}", err=True)
        return
    if fmt is OutputFormat.csv:
        import io

        buf = io.BytesIO()
        pacsv.write_csv(_flatten_lists_for_csv(result), buf)
        text = buf.getvalue().decode()
    elif fmt is OutputFormat.json:
        import json

        text = "\n".join(json.dumps(r, default=str) for r in result.to_pylist()) + ("\n" if result.num_rows else "")
    else:
        text = _pretty(result, max_rows)
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text)
        typer.echo(f"wrote {result.num_rows} rows to {output}", err=True)


def _flatten_lists_for_csv(result):
    """CSV has no arrays: list columns are written as JSON text."""
    import json

    import pyarrow as pa

    cols = []
    for name in result.column_names:
        col = result.column(name)
        t = col.type
        if pa.types.is_list(t) or pa.types.is_fixed_size_list(t) or pa.types.is_large_list(t) or pa.types.is_struct(t):
            col = pa.array([json.dumps(v) for v in col.to_pylist()], pa.string())
        cols.append(col)
    return pa.table(cols, names=result.column_names)


def _pretty(result, max_rows: int) -> str:
    import duckdb

    con = duckdb.connect()
    try:
        rel = con.from_arrow(result)
        text = rel.limit(max_rows).__str__() if result.num_rows > max_rows else str(rel)
    finally:
        con.close()
    if result.num_rows > max_rows:
        text += f"({result.num_rows} rows, {max_rows} shown; use --max-rows or --format csv)\n"
    return text


@app.command()
def catalog() -> None:
    """Rebuild warehouse/catalog.duckdb: one DuckDB view per table, over its Parquet files."""
    from demoforge.schemas.catalog import build_catalog  # lazy (CLI start-up): duckdb, pyarrow

    path = build_catalog(current_warehouse())
    typer.echo(f"catalog rebuilt: {path}")


@app.command()
def tables(
    name: Optional[str] = typer.Argument(None, help="Describe this table column by column."),
) -> None:
    """List the warehouse tables with their row counts, or describe one table's columns."""
    # lazy (CLI start-up): pyarrow
    from demoforge.schemas import registry
    from demoforge.schemas.core import ALL_VARIANTS, get_schema, table_files

    root = current_warehouse()
    if name:
        try:
            schema = get_schema(name)
        except KeyError as e:
            raise fail(str(e.args[0]))
        typer.echo(schema.describe())
        return
    from demoforge.schemas.core import parquet_metadata  # lazy (CLI start-up): pyarrow

    lines = []  # all read before any is printed: a damaged file is the one line of output
    for tname, schema in sorted(registry().items()):
        files = table_files(tname, root, ALL_VARIANTS)  # a second detector's rows too (demoforge.schemas.core.variant_parts)
        rows = sum(parquet_metadata(f, tname).num_rows for f in files)
        lines.append(f"{tname:<24} v{schema.version}  {rows:>10} rows  {len(files):>5} files  {schema.doc.splitlines()[0][:70]}")
    typer.echo("\n".join(lines))
