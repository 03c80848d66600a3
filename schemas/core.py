"""Table contracts: one versioned pyarrow schema per warehouse table, one validating writer, one reader.

Every table in the warehouse is declared once with :func:`table` (name, version, columns with their
units and frames, partition columns). :func:`write_table` is the only way anything is written to the
warehouse: it checks the data against the contract, refuses a mismatch with an error naming the
column, and replaces the partition's file atomically (temporary file in the same folder, fsync,
``os.replace``), so a reader never sees a half-written file and a failed write leaves the previous
file untouched.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import pyarrow as pa
import pyarrow.parquet as pq

from demoforge.lib.errors import UserError

DATA_FILE = "data.parquet"
_SAFE_PART = re.compile(r"^[A-Za-z0-9_.\-]+$")


class SchemaError(ValueError):
    """Data does not match a table's contract; the message names the table and the column."""


class WarehouseDamaged(UserError):
    """A table file in the warehouse cannot be read (truncated or overwritten on disk)."""


def damaged_file_error(path: str | os.PathLike, table: str, error: BaseException) -> WarehouseDamaged:
    """The one-line error for an unreadable table file: which file, why, and how to get it back."""
    why = " ".join(str(error).split())[:160] or type(error).__name__
    return WarehouseDamaged(
        f"{path}: damaged warehouse file ({why}); run the command that wrote table {table!r} again (a "
        "cached stage whose output file changed or is gone is recomputed), or delete the file to drop its rows")


# What pyarrow raises for a file that is not (or no longer) Parquet: ArrowInvalid for bad magic bytes
# or a footer cut short, OSError for what cannot be read at all.
_UNREADABLE = (pa.ArrowException, OSError)


def read_parquet_file(path: str | os.PathLike, table: str, columns: Sequence[str] | None = None) -> pa.Table:
    """``pq.read_table`` of one file of warehouse table ``table``; a damaged file is a
    :class:`WarehouseDamaged` naming it and the fix, never a pyarrow traceback."""
    try:
        return pq.read_table(path, columns=list(columns) if columns is not None else None)
    except _UNREADABLE as e:
        raise damaged_file_error(path, table, e) from None


def parquet_metadata(path: str | os.PathLike, table: str) -> pq.FileMetaData:
    """The footer of one file of warehouse table ``table`` (row count, schema); damaged: as :func:`read_parquet_file`."""
    try:
        return pq.ParquetFile(path).metadata
    except _UNREADABLE as e:
        raise damaged_file_error(path, table, e) from None


@dataclass(frozen=True)
class Column:
    name: str
    type: pa.DataType
    doc: str
    nullable: bool = False


def metric_column(name: str, doc: str) -> Column:
    """A float64 metric that may be null (NaN or missing when nothing could be measured)."""
    return Column(name, pa.float64(), doc, nullable=True)


@dataclass(frozen=True)
class TableSchema:
    name: str
    version: int
    doc: str
    columns: tuple[Column, ...]
    partition_by: tuple[str, ...] = ()

    @property
    def arrow(self) -> pa.Schema:
        fields = [
            pa.field(c.name, c.type, nullable=c.nullable, metadata={"doc": c.doc})
            for c in self.columns
        ]
        return pa.schema(
            fields,
            metadata={
                "demoforge.table": self.name,
                "demoforge.schema_version": str(self.version),
                "demoforge.doc": self.doc,
            },
        )

    def column(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise KeyError(f"table {self.name!r} has no column {name!r}")

    def describe(self) -> str:
        """A Markdown description of the table, column by column."""
        lines = [f"### `{self.name}` (schema v{self.version})", "", self.doc, ""]
        if self.partition_by:
            lines += [f"Partitioned by: {', '.join(self.partition_by)}", ""]
        lines += ["| column | type | null | meaning |", "|---|---|---|---|"]
        for c in self.columns:
            lines.append(f"| `{c.name}` | `{c.type}` | {'yes' if c.nullable else 'no'} | {c.doc} |")
        return "\n".join(lines) + "\n"


_REGISTRY: dict[str, TableSchema] = {}


def table(
    name: str,
    version: int,
    doc: str,
    columns: Sequence[Column],
    partition_by: Sequence[str] = (),
) -> TableSchema:
    """Declare a table contract and register it under its name."""
    names = [c.name for c in columns]
    if len(set(names)) != len(names):
        raise ValueError(f"table {name!r} declares a column twice: {names}")
    for p in partition_by:
        if p not in names:
            raise ValueError(f"table {name!r} partitions by unknown column {p!r}")
    schema = TableSchema(name, version, doc, tuple(columns), tuple(partition_by))
    if name in _REGISTRY and _REGISTRY[name] != schema:
        raise ValueError(f"table {name!r} is declared twice with different contracts")
    _REGISTRY[name] = schema
    return schema


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


def registry() -> Mapping[str, TableSchema]:
    return dict(_REGISTRY)


def get_schema(name: str) -> TableSchema:
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY)) or "(none)"
        raise KeyError(f"unknown table {name!r}; known tables: {known}") from None


# --- common column types -------------------------------------------------------------------------

def vec3() -> pa.DataType:
    return pa.list_(pa.float64(), 3)


def fixed_list(value_type: pa.DataType, size: int) -> pa.DataType:
    return pa.list_(value_type, size)


def keypoints3d(n: int) -> pa.DataType:
    """n x 3 points as a fixed-size list of fixed-size lists."""
    return pa.list_(pa.list_(pa.float64(), 3), n)


def keypoints2d(n: int) -> pa.DataType:
    return pa.list_(pa.list_(pa.float64(), 2), n)


def pose8() -> pa.DataType:
    """[x, y, z, qx, qy, qz, qw, g]: world-frame position (m), unit quaternion (scalar-last), gripper 1=open."""
    return pa.list_(pa.float64(), 8)


def dual_pose8() -> pa.DataType:
    """2 x 8: arm 0 = left, arm 1 = right."""
    return pa.list_(pa.list_(pa.float64(), 8), 2)


def matrix4() -> pa.DataType:
    return pa.list_(pa.list_(pa.float64(), 4), 4)


# --- validation ----------------------------------------------------------------------------------

def _fixed_shape(t: pa.DataType) -> list[int]:
    shape = []
    while pa.types.is_fixed_size_list(t):
        shape.append(t.list_size)
        t = t.value_type
    return shape


def _coerce_column(schema: TableSchema, col: Column, values: pa.ChunkedArray | pa.Array) -> pa.Array:
    """Cast one column to its contract type, or raise SchemaError naming it."""
    where = f"table {schema.name!r}, column {col.name!r}"
    actual = values.type
    if actual == col.type:
        out = values
    else:
        expected_shape = _fixed_shape(col.type)
        if expected_shape:
            # Accept variable-size lists (e.g. from pandas/numpy) only if every row has the exact shape.
            depth = 0
            t = actual
            while pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_fixed_size_list(t):
                depth += 1
                t = t.value_type
            if depth != len(expected_shape):
                raise SchemaError(
                    f"{where}: expected {col.type} (shape {expected_shape}), got {actual}"
                )
            try:
                out = values.cast(col.type)
            except pa.ArrowException as e:
                raise SchemaError(
                    f"{where}: expected fixed shape {expected_shape} of {col.type}; {e}"
                ) from None
        else:
            if not _castable_scalar(actual, col.type):
                raise SchemaError(f"{where}: expected {col.type}, got {actual}")
            try:
                out = values.cast(col.type, safe=True)
            except pa.ArrowException as e:
                raise SchemaError(f"{where}: cannot store {actual} as {col.type}: {e}") from None
    if not col.nullable and out.null_count:
        raise SchemaError(f"{where}: {out.null_count} null value(s) in a non-nullable column")
    if not col.nullable and _fixed_shape(col.type):
        # Nulls nested inside fixed-size lists (e.g. a missing coordinate) are refused too.
        flat = out
        if isinstance(flat, pa.ChunkedArray):
            flat = flat.combine_chunks()
        while pa.types.is_fixed_size_list(flat.type):
            flat = flat.flatten()
        if flat.null_count:
            raise SchemaError(f"{where}: {flat.null_count} null element(s) inside its fixed-size lists")
    return out


def _castable_scalar(actual: pa.DataType, expected: pa.DataType) -> bool:
    """Only lossless-in-kind casts: ints widen to ints/floats, floats to floats, strings to strings."""
    if pa.types.is_null(actual):
        return True
    groups = [
        (pa.types.is_integer, (pa.types.is_integer, pa.types.is_floating)),
        (pa.types.is_floating, (pa.types.is_floating,)),
        (lambda t: pa.types.is_string(t) or pa.types.is_large_string(t),
         (pa.types.is_string, pa.types.is_large_string, pa.types.is_dictionary)),
        (pa.types.is_boolean, (pa.types.is_boolean,)),
        (pa.types.is_timestamp, (pa.types.is_timestamp,)),
        (pa.types.is_dictionary, (pa.types.is_string, pa.types.is_dictionary)),
    ]
    for is_src, targets in groups:
        if is_src(actual):
            return any(f(expected) for f in targets)
    return False


def validate(schema: TableSchema | str, data: pa.Table | Any) -> pa.Table:
    """Return ``data`` as a pyarrow Table exactly in the contract's schema, or raise SchemaError."""
    if isinstance(schema, str):
        schema = get_schema(schema)
    tbl = _as_arrow(data)
    present = set(tbl.column_names)
    expected = [c.name for c in schema.columns]
    missing = [n for n in expected if n not in present]
    extra = [n for n in tbl.column_names if n not in expected]
    if missing:
        raise SchemaError(f"table {schema.name!r}: missing column(s) {missing}")
    if extra:
        raise SchemaError(f"table {schema.name!r}: unexpected column(s) {extra}")
    arrays = [_coerce_column(schema, c, tbl.column(c.name)) for c in schema.columns]
    return pa.Table.from_arrays(arrays, schema=schema.arrow)


def _as_arrow(data: Any) -> pa.Table:
    if isinstance(data, pa.Table):
        return data
    if isinstance(data, Mapping):
        return pa.table({k: _to_arrow_values(v) for k, v in data.items()})
    try:
        import pandas as pd
    except ImportError:  # pragma: no cover - pandas is a dependency
        pd = None
    if pd is not None and isinstance(data, pd.DataFrame):
        return pa.table({k: _to_arrow_values(data[k].to_list()) for k in data.columns})
    raise TypeError(f"cannot write {type(data).__name__}; pass a pyarrow Table, DataFrame or dict of columns")


def _to_arrow_values(v: Any) -> pa.Array:
    import numpy as np

    if isinstance(v, (pa.Array, pa.ChunkedArray)):
        return v
    if isinstance(v, np.ndarray) and v.ndim > 1:
        # (rows, *shape) -> nested fixed-size lists without a Python loop.
        arr = pa.array(np.ascontiguousarray(v).reshape(-1))
        for size in reversed(v.shape[1:]):
            arr = pa.FixedSizeListArray.from_arrays(arr, size)
        return arr
    return pa.array(v)


def column_numpy(table: pa.Table, name: str):
    """A column as a numpy array; nested fixed-size lists become trailing dimensions (rows, *shape)."""
    import numpy as np

    col = table.column(name).combine_chunks()
    shape: list[int] = []
    t = col.type
    while pa.types.is_fixed_size_list(t):
        shape.append(t.list_size)
        t = t.value_type
    flat = col
    for _ in shape:
        flat = flat.flatten()
    return np.asarray(flat.to_numpy(zero_copy_only=False)).reshape((len(col),) + tuple(shape))


# --- writing and reading -------------------------------------------------------------------------

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


@dataclass(frozen=True)
class WrittenFile:
    table: str
    path: str
    rows: int
    content_hash: str
    partition: dict = field(default_factory=dict)


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


def atomic_write_parquet(tbl: pa.Table, target: Path) -> str:
    """Write ``tbl`` to ``target`` via a temporary file in the same folder and an atomic rename.

    Returns the sha256 of the written bytes.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            pq.write_table(tbl, fh, compression="zstd")
            fh.flush()
            os.fsync(fh.fileno())
        digest = file_sha256(tmp)
        os.replace(tmp, target)
        _fsync_dir(target.parent)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return digest


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


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


def write_table_file(name: str, data: Any, path: str | os.PathLike) -> WrittenFile:
    """Validate ``data`` against table ``name`` and write it atomically to one file at ``path``.

    For tables stored outside the warehouse layout, e.g. the ground truth beside a synthetic take.
    """
    tbl = validate(name, data)
    digest = atomic_write_parquet(tbl, Path(path))
    return WrittenFile(name, str(path), tbl.num_rows, digest)


def read_table_file(name: str, path: str | os.PathLike) -> pa.Table:
    """Read one file written by :func:`write_table_file`, checking its table name and version."""
    schema = get_schema(name)
    t = pq.read_table(path)
    meta = t.schema.metadata or {}
    found = (meta.get(b"demoforge.table", b"?").decode(), meta.get(b"demoforge.schema_version", b"?").decode())
    if found != (schema.name, str(schema.version)):
        raise SchemaError(
            f"{path}: holds table {found[0]!r} v{found[1]}, expected {schema.name!r} v{schema.version}"
        )
    return t.cast(schema.arrow)
