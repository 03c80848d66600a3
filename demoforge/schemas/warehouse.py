"""The warehouse layout: one folder per table, hive-style partition and variant folders, one ``data.parquet``
per partition; the validating writer and the reader of whole tables."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import pyarrow as pa

from demoforge.schemas.contracts import SchemaError, TableSchema, get_schema
from demoforge.schemas.files import WrittenFile, atomic_write_parquet, read_parquet_file
from demoforge.schemas.validation import validate

DATA_FILE = "data.parquet"
_SAFE_PART = re.compile(r"^[A-Za-z0-9_.\-]+$")


def _safe_value(schema: TableSchema, what: str, v: Any) -> str:
    v = str(v)
    if not _SAFE_PART.match(v) or v in (".", ".."):
        raise SchemaError(
            f"table {schema.name!r}, {what}: value {v!r} may only contain letters, digits, '_', '-' and '.'"
        )
    return v


def variant_parts(schema: TableSchema, variant: Mapping[str, Any] | None) -> list[str]:
    """The folders ``key=value`` (sorted by key) of a table *variant*: rows of the same partitions
    computed another way, e.g. ``{"detector": "mediapipe"}``, kept beside the default rows under
    ``<table>/detector=mediapipe/...`` (hive-style, so SQL over ``**/data.parquet`` sees both). The
    default rows (variant None) keep their paths. A variant key must be a column of the table that
    is not a partition column; every row written under it holds that value (checked on write)."""
    if not variant:
        return []
    out = []
    for k in sorted(variant):
        if k in schema.partition_by or k not in {c.name for c in schema.columns}:
            raise SchemaError(f"table {schema.name!r}: variant key {k!r} must be a column that is not a partition column")
        out.append(f"{k}={_safe_value(schema, f'variant {k!r}', variant[k])}")
    return out


def partition_dir(root: Path, schema: TableSchema, values: Mapping[str, Any],
                  variant: Mapping[str, Any] | None = None) -> Path:
    d = Path(root) / schema.name
    for part in variant_parts(schema, variant):
        d = d / part
    for p in schema.partition_by:
        d = d / f"{p}={_safe_value(schema, f'partition column {p!r}', values[p])}"
    return d


def write_table(name: str | TableSchema, data: Any, root: str | os.PathLike,
                variant: Mapping[str, Any] | None = None) -> list[WrittenFile]:
    """Validate ``data`` against table ``name`` and write it under ``root/<name>/``.

    A partitioned table writes one file per distinct partition value combination found in the data,
    each replacing that partition's previous file atomically; partitions not in ``data`` are left as
    they are. An unpartitioned table replaces its single file.
    ``variant`` (e.g. ``{"detector": "mediapipe"}``): write under that variant's folders instead
    (:func:`variant_parts`); every row must hold the variant's value in that column.
    """
    schema = name if isinstance(name, TableSchema) else get_schema(name)
    tbl = validate(schema, data)
    root = Path(root)
    variant_parts(schema, variant)  # the keys and values are checked even for an empty table
    for k, v in (variant or {}).items():
        wrong = set(tbl.column(k).to_pylist()) - {v}
        if wrong:
            raise SchemaError(f"table {schema.name!r}: rows with {k} {sorted(map(str, wrong))} written under "
                              f"variant {k}={v}")
    if not schema.partition_by:
        groups = [({}, tbl)]
    else:
        groups = _split_partitions(tbl, schema.partition_by)
    written = []
    for values, part in groups:
        target = partition_dir(root, schema, values, variant) / DATA_FILE
        digest = atomic_write_parquet(part, target)
        written.append(WrittenFile(schema.name, str(target), part.num_rows, digest, dict(values)))
    return written


def _unsliced(arr: pa.Array) -> pa.Array:
    """The same values with offset 0 at every fixed-size-list level. pyarrow 26.0.1's filter and take
    return wrong rows for a nested fixed-size-list array that is a slice (as Parquet reads and
    Table.slice give): the inner offset is ignored. Rebuilding from the flattened values avoids it."""
    if pa.types.is_fixed_size_list(arr.type):
        mask = arr.is_null() if arr.null_count else None
        return pa.FixedSizeListArray.from_arrays(_unsliced(arr.flatten()), type=arr.type, mask=mask)
    return arr


def unsliced_table(tbl: pa.Table) -> pa.Table:
    """``tbl`` with every fixed-size-list column rebuilt at offset 0 (see :func:`_unsliced`)."""
    cols = []
    for name in tbl.column_names:
        col = tbl.column(name)
        if pa.types.is_fixed_size_list(col.type):
            col = pa.chunked_array([_unsliced(c) for c in col.chunks], type=col.type)
        cols.append(col)
    return pa.Table.from_arrays(cols, schema=tbl.schema)


def _split_partitions(tbl: pa.Table, cols: Sequence[str]) -> list[tuple[dict, pa.Table]]:
    import pyarrow.compute as pc

    tbl = unsliced_table(tbl)

    if tbl.num_rows == 0:
        raise SchemaError("cannot write an empty partitioned table: the partition is unknown")
    keys = tbl.select(list(cols)).group_by(list(cols)).aggregate([]).to_pylist()
    out = []
    for key in keys:
        mask = None
        for c in cols:
            m = pc.equal(tbl.column(c), key[c])
            mask = m if mask is None else pc.and_(mask, m)
        out.append((key, tbl.filter(mask)))
    return out


ALL_VARIANTS = "*"


def table_files(name: str, root: str | os.PathLike, variant: Mapping[str, Any] | str | None = None,
                **partition: Any) -> list[Path]:
    """The data files of a table (optionally of one partition), sorted; temporary files excluded.
    ``variant``: None the default rows, a dict one variant's (:func:`variant_parts`), ``ALL_VARIANTS``
    the default rows and every variant's."""
    schema = get_schema(name)
    base = Path(root) / schema.name
    if not base.exists():
        return []
    if variant == ALL_VARIANTS:
        files = table_files(name, root, None, **partition)
        for d in sorted(p for p in base.iterdir() if p.is_dir() and "=" in p.name
                        and p.name.split("=", 1)[0] not in schema.partition_by):
            key, value = d.name.split("=", 1)
            files += table_files(name, root, {key: value}, **partition)
        return sorted(files)
    base = base.joinpath(*variant_parts(schema, variant))  # type: ignore[arg-type]
    if not base.exists():
        return []
    pattern_parts = []
    for p in schema.partition_by:
        pattern_parts.append(f"{p}={partition.pop(p)}" if p in partition else f"{p}=*")
    if partition:
        raise KeyError(f"table {name!r} is not partitioned by {sorted(partition)}")
    return sorted(base.glob("/".join(pattern_parts + [DATA_FILE])))


def read_table(
    name: str,
    root: str | os.PathLike,
    columns: Iterable[str] | None = None,
    variant: Mapping[str, Any] | str | None = None,
    **partition: Any,
) -> pa.Table:
    """Read a table (or one partition of it) in its contract's schema; empty if nothing was written.
    ``variant``: as for :func:`table_files` (default: the default rows only)."""
    schema = get_schema(name)
    files = table_files(name, root, variant, **partition)
    cols = list(columns) if columns is not None else None
    target_schema = schema.arrow if cols is None else pa.schema([schema.arrow.field(c) for c in cols])
    if not files:
        return target_schema.empty_table()
    parts = []
    for f in files:
        t = read_parquet_file(f, name, cols)
        version = (t.schema.metadata or {}).get(b"demoforge.schema_version", b"?").decode()
        if version != str(schema.version):
            raise SchemaError(
                f"table {name!r}: {f} has schema version {version}, this code reads version "
                f"{schema.version}; re-run the stage that writes it"
            )
        parts.append(t.cast(target_schema))
    return pa.concat_tables(parts)
