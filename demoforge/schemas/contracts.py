"""A table contract: its columns (type, unit, frame, nullability), version and partition columns, and the
registry of every declared table. Pure declaration: nothing here reads or writes a file."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import pyarrow as pa


class SchemaError(ValueError):
    """Data does not match a table's contract; the message names the table and the column."""


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


def registry() -> Mapping[str, TableSchema]:
    return dict(_REGISTRY)


def get_schema(name: str) -> TableSchema:
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY)) or "(none)"
        raise KeyError(f"unknown table {name!r}; known tables: {known}") from None
