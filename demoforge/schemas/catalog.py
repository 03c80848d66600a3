"""The warehouse location, its DuckDB catalog (views only) and read-only SQL over it.

``warehouse/catalog.duckdb`` holds one view per registered table (reading that table's Parquet files
with the contract's exact types, fixed-size ARRAYs included) and one view ``_catalog`` that records
which warehouse and which files the views were built for. It holds no data: deleting it loses
nothing, ``demoforge catalog`` (or any ``demoforge sql``) rebuilds it.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from datetime import datetime, timezone
from pathlib import Path

from typing import Any, Sequence

import duckdb
import pyarrow as pa

from demoforge.lib.errors import UserError

from demoforge.schemas.core import (  # noqa: F401  (WarehouseDamaged: its old home)
    DATA_FILE, TableSchema, WarehouseDamaged, migrate_warehouse, parquet_metadata, registry,
)
from demoforge.lib.settings import read_settings
from demoforge.schemas.reports import REPORT_VIEWS, TABLE_VIEWS

CATALOG_FILE = "catalog.duckdb"
ENV_WAREHOUSE = "DEMOFORGE_WAREHOUSE"
PROJECT_ROOT = Path(__file__).resolve().parents[2]

# Statement types a query through `demoforge sql` may contain. DESCRIBE/SHOW parse as SELECT.
_READ_ONLY_TYPES = {duckdb.StatementType.SELECT}


class QueryRefused(UserError):
    """The query would write, or is not a single read-only statement."""


def warehouse_root(explicit: str | os.PathLike | None = None) -> Path:
    """``explicit`` if given, else ``$DEMOFORGE_WAREHOUSE``, else the checkout's ``warehouse/`` (the
    design card's top-level folder) when demoforge runs from a checkout, and ``./warehouse`` of the
    current directory when it is an installed package (never a folder inside site-packages)."""
    if explicit:
        return Path(explicit).expanduser().resolve()
    configured = read_settings().warehouse
    if configured:
        return configured.resolve()
    if (PROJECT_ROOT / "pyproject.toml").is_file():
        return (PROJECT_ROOT / "warehouse").resolve()
    return (Path.cwd() / "warehouse").resolve()


def _sql_literal(s: str) -> str:
    """A quoted SQL string: only for the catalog's view definitions (DDL takes no parameters); every
    query passes its values as parameters (``query(sql, root, params)``)."""
    return "'" + s.replace("'", "''") + "'"


_TYPES: dict[pa.Schema, list[str]] = {}
_TYPES_LOCK = threading.Lock()
_TYPES_CONNECTION: list[duckdb.DuckDBPyConnection] = []  # one in-memory connection, made on first use


def _duckdb_types(schema: TableSchema) -> list[str]:
    """The DuckDB type of each column of the contract. Asked of DuckDB once per contract and process,
    on one connection: each catalog build needs all of them, and a fresh connection per contract per
    build made them most of the build's time (about 0.5 s for 30 tables)."""
    arrow = schema.arrow
    with _TYPES_LOCK:
        if arrow not in _TYPES:
            if not _TYPES_CONNECTION:
                _TYPES_CONNECTION.append(duckdb.connect())
            _TYPES[arrow] = [str(t) for t in _TYPES_CONNECTION[0].from_arrow(arrow.empty_table()).types]
        return list(_TYPES[arrow])


def _view_sql(root: Path, schema: TableSchema) -> str:
    types = _duckdb_types(schema)
    files = list((root / schema.name).glob("**/" + DATA_FILE))
    if files:
        cols = ", ".join(f'CAST("{c.name}" AS {t}) AS "{c.name}"' for c, t in zip(schema.columns, types))
        glob = _sql_literal(str(root / schema.name) + "/**/" + DATA_FILE)
        source = f"read_parquet({glob}, hive_partitioning = false)"
        return f'CREATE VIEW "{schema.name}" AS SELECT {cols} FROM {source}'
    # No data yet: an empty view with the contract's columns, so queries still bind.
    cols = ", ".join(f'CAST(NULL AS {t}) AS "{c.name}"' for c, t in zip(schema.columns, types))
    return f'CREATE VIEW "{schema.name}" AS SELECT {cols} WHERE false'


def catalog_fingerprint(root: Path) -> str:
    """Changes whenever a table gains or loses files, a contract changes, or the warehouse moves."""
    h = hashlib.sha256(str(root).encode())
    h.update(repr(sorted(TABLE_VIEWS.items())).encode())
    h.update(repr(sorted(REPORT_VIEWS.items())).encode())
    for name, schema in sorted(registry().items()):
        h.update(f"{name}:{schema.version}:{[(c.name, str(c.type)) for c in schema.columns]}".encode())
        for f in sorted((root / name).glob("**/" + DATA_FILE)):
            h.update(str(f.relative_to(root)).encode())
    return h.hexdigest()


def build_catalog(root: str | os.PathLike | None = None) -> Path:
    """(Re)build ``<root>/catalog.duckdb`` atomically: built in a temporary file, then renamed."""
    root = warehouse_root(root)
    root.mkdir(parents=True, exist_ok=True)
    migrate_warehouse(root)  # files of older table contracts first, so the views see one layout
    target = root / CATALOG_FILE
    fd, tmp = tempfile.mkstemp(prefix=".catalog.", suffix=".duckdb", dir=root)
    os.close(fd)
    os.unlink(tmp)  # duckdb must create the file itself
    try:
        con = duckdb.connect(tmp)
        try:
            for schema in registry().values():
                try:
                    con.execute(_view_sql(root, schema))
                except duckdb.Error as e:
                    _raise_if_damaged(root, schema.name, e)
                    raise
            for name, sql in (*TABLE_VIEWS.items(), *REPORT_VIEWS.items()):
                con.execute(f'CREATE VIEW "{name}" AS {sql}')
            built = datetime.now(timezone.utc).isoformat(timespec="seconds")
            con.execute(
                "CREATE VIEW _catalog AS SELECT "
                f"{_sql_literal(str(root))} AS warehouse, "
                f"{_sql_literal(catalog_fingerprint(root))} AS fingerprint, "
                f"{_sql_literal(built)} AS built_at"
            )
        finally:
            con.close()
        os.replace(tmp, target)
    finally:
        for leftover in (tmp, tmp + ".wal"):
            if os.path.exists(leftover):
                os.unlink(leftover)
    return target


def _raise_if_damaged(root: Path, table: str, error: BaseException) -> None:
    """Name the first unreadable Parquet file of ``table`` and the fix, if one is the cause of ``error``."""
    for f in sorted((root / table).glob("**/" + DATA_FILE)):
        parquet_metadata(f, table)  # footer and schema: what the view needs


def catalog_is_current(root: Path) -> bool:
    target = root / CATALOG_FILE
    if not target.exists():
        return False
    try:
        con = duckdb.connect(str(target), read_only=True)
        try:
            (fp,) = con.execute("SELECT fingerprint FROM _catalog").fetchone()
        finally:
            con.close()
    except duckdb.Error:
        return False
    return fp == catalog_fingerprint(root)


def check_read_only(sql: str) -> None:
    """Raise QueryRefused unless ``sql`` is exactly one read-only statement."""
    con = duckdb.connect()
    try:
        statements = con.extract_statements(sql)
    except duckdb.Error as e:
        raise QueryRefused(_one_line(e)) from None
    finally:
        con.close()
    if not statements:
        raise QueryRefused("empty query: give one SELECT statement")
    if len(statements) > 1:
        raise QueryRefused(f"{len(statements)} statements given; `demoforge sql` runs exactly one SELECT")
    kind = statements[0].type
    if kind not in _READ_ONLY_TYPES:
        name = str(kind).rsplit(".", 1)[-1]
        raise QueryRefused(
            f"{name} refused: `demoforge sql` is read-only; tables are written only by the pipeline's stages"
        )


def query(sql: str, root: str | os.PathLike | None = None, params: Sequence[Any] | dict | None = None) -> pa.Table:
    """Run one read-only statement against the warehouse catalog and return the result. Values go in
    ``params`` (DuckDB ``?`` or ``$name`` parameters), never spliced into ``sql``: a task or take name
    is data, not SQL."""
    check_read_only(sql)
    root = warehouse_root(root)
    if not catalog_is_current(root):
        build_catalog(root)
    con = confined_connection(root)
    try:
        result = con.sql(sql, params=params).arrow()
        # duckdb >= 2 returns a RecordBatchReader here, older versions a Table.
        return result.read_all() if hasattr(result, "read_all") else result
    except duckdb.PermissionException as e:
        raise QueryRefused(f"refused: queries read only the warehouse's tables ({_one_line(e)})") from None
    except duckdb.Error as e:
        _raise_if_damaged_file(root, e)
        raise QueryRefused(_one_line(e)) from None
    finally:
        con.close()


def _raise_if_damaged_file(root: Path, error: BaseException) -> None:
    """A query failed on a current catalog: if a table file was damaged since the catalog was built, say
    which and how to fix it (the tables the error names, else every table: only on this error path)."""
    text = str(error)
    named = [name for name in registry() if str(root / name) + os.sep in text]
    for name in named or sorted(registry()):
        _raise_if_damaged(root, name, error)


def placeholders(n: int) -> str:
    """``?, ?, ...`` for an ``IN (...)`` list of ``n`` parameters (``NULL`` for none: ``IN ()`` is a syntax error)."""
    return ", ".join("?" * n) or "NULL"


def confined_connection(root: Path) -> duckdb.DuckDBPyConnection:
    """A read-only connection to ``root``'s catalog that can read the tables' Parquet files and nothing else.

    The SQL door takes user text (``demoforge sql``, ``--task`` values in report queries), so it must
    not open onto the rest of the file system: with external access off, ``read_text('/etc/passwd')``,
    ``read_csv``, ``glob``, ``ATTACH``, ``INSTALL``/``LOAD`` and http(s) reads are refused; only the
    table folders (not ``_prefect/`` or anything else under the warehouse) stay readable. The
    configuration is then locked, so a query cannot ``SET`` it back (nor change anything else).
    These settings can only be set once the database is open, hence the SET statements here.
    """
    con = duckdb.connect(str(root / CATALOG_FILE), read_only=True,
                         config={"autoinstall_known_extensions": False, "autoload_known_extensions": False})
    try:
        con.execute("SET allowed_directories = ?", [[str(root / name) + os.sep for name in sorted(registry())]])
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
    except BaseException:
        con.close()
        raise
    return con


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return text if len(text) <= 400 else text[:397] + "..."
