"""Migrations: what brings a table's files written under an older contract to the current one."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Mapping

import pyarrow as pa

from demoforge.schemas.contracts import get_schema
from demoforge.schemas.files import atomic_write_parquet, parquet_metadata, read_parquet_file
from demoforge.schemas.validation import validate
from demoforge.schemas.warehouse import DATA_FILE

_MIGRATIONS: list[tuple[str, Callable[[Path], int]]] = []


def register_migration(table_name: str, migrate: Callable[[Path], int]) -> None:
    """Register ``migrate(root) -> files changed``, which brings a table's files written under an older
    contract to the current one. It must be idempotent and cheap when there is nothing to do."""
    _MIGRATIONS.append((table_name, migrate))


def added_columns_migration(name: str, old_version: int, values: Mapping[str, Any]) -> Callable[[Path], int]:
    """The migration of a table whose contract gained columns since ``old_version``: each file of that
    version gets them, filled with ``values[column]`` (NaN: not measured then), in the current contract
    (rewritten atomically, where it is). A stage whose cached output it changed runs again when asked."""
    def migrate(root: Path) -> int:
        schema = get_schema(name)
        changed = 0
        for f in sorted((Path(root) / name).glob("**/" + DATA_FILE)):
            meta = parquet_metadata(f, name).metadata or {}
            if meta.get(b"demoforge.schema_version") != str(old_version).encode():
                continue
            t = read_parquet_file(f, name)
            for column, value in values.items():
                t = t.append_column(column, pa.array([value] * t.num_rows, schema.column(column).type))
            atomic_write_parquet(validate(schema, t), f)
            changed += 1
        return changed

    return migrate


def migrate_warehouse(root: str | os.PathLike) -> dict[str, int]:
    """Run every registered migration on the warehouse at ``root``; {table: files changed} where any."""
    done = {}
    for name, fn in _MIGRATIONS:
        n = fn(Path(root))
        if n:
            done[name] = n
    return done
