"""One Parquet file on disk: written atomically (temporary file, fsync, ``os.replace``) and hashed, read
back with a one-line error when it is damaged."""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import pyarrow as pa
import pyarrow.parquet as pq

from demoforge.lib.errors import UserError
from demoforge.schemas.contracts import SchemaError, get_schema
from demoforge.schemas.validation import validate


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
class WrittenFile:
    table: str
    path: str
    rows: int
    content_hash: str
    partition: dict = field(default_factory=dict)


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
