"""A warehouse table read for comparison between two runs: volatile columns dropped, rows in a canonical order."""

from pathlib import Path

import pyarrow as pa

from demoforge.schemas.core import read_table


def canonical_table(warehouse: Path, name: str, volatile: set[str]) -> pa.Table:
    """Table `name` of the warehouse without the `volatile` columns (wall-clock timings), sorted by every
    scalar column."""
    t = read_table(name, warehouse)
    t = t.drop_columns([c for c in t.column_names if c in volatile])
    keys = [f.name for f in t.schema if not (pa.types.is_list(f.type) or pa.types.is_fixed_size_list(f.type)
                                              or pa.types.is_struct(f.type))]
    return t.sort_by([(k, "ascending") for k in keys])
