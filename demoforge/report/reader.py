"""One report run's reads of the warehouse catalog."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import pyarrow as pa

from demoforge.schemas.catalog import query


class ViewReader:
    """A run's reads of one warehouse: each view (or table) of the catalog is queried once, however often
    the Markdown, the CSVs, the figures and the Prefect artifacts of the run ask for it. Made per run:
    nothing is kept between runs."""

    def __init__(self, warehouse: str | os.PathLike):
        self.warehouse = Path(warehouse)
        self._views: dict[str, pa.Table] = {}

    def view(self, name: str) -> pa.Table:
        """Every row of the view (or table) ``name``."""
        if name not in self._views:
            self._views[name] = query(f"SELECT * FROM {name}", self.warehouse)
        return self._views[name]

    def query(self, sql: str, params: Sequence[Any] | None = None) -> pa.Table:
        """One read-only statement (not remembered: a figure's or a dataset's own selection)."""
        return query(sql, self.warehouse, params)
