"""Benchmark cases of the warehouse stage (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demoforge.bench.timing import BenchCase
from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.schemas import catalog
from demoforge.schemas.core import Column, TableSchema, keypoints3d, registry, write_table


# Not registered: a scratch table for the benchmark only, so it never shows in the catalog.
_SCRATCH = TableSchema("_bench_keypoints", 1, "warehouse benchmark scratch table", (
    Column("frame", pa.int64(), "row index"), Column("joints", keypoints3d(21), "random joints")))


def cases(quick: bool) -> list[BenchCase]:
    rows = 20_000 if quick else 200_000

    def setup(n: int):
        rng = np.random.default_rng(0)
        joints = rng.normal(size=(n, 21, 3))
        frame = np.arange(n, dtype=np.int64)
        tmp = folder_removed_at_exit("demoforge-bench-")

        def fast():
            return write_table(_SCRATCH, {"frame": frame, "joints": joints}, tmp / "fast")

        def baseline():
            # What one writes without the vectorised conversion: Python lists row by row.
            t = pa.table({"frame": frame.tolist(), "joints": [j.tolist() for j in joints]})
            t = t.cast(pa.schema([("frame", pa.int64()), ("joints", pa.list_(pa.list_(pa.float64(), 3), 21))]))
            (tmp / "base").mkdir(exist_ok=True)
            pq.write_table(t, tmp / "base" / "data.parquet", compression="zstd")
            return t.num_rows

        return fast, baseline

    def catalog_setup(n: int):
        root = folder_removed_at_exit("demoforge-bench-") / "warehouse"

        def views(path: Path) -> list[tuple[str, str]]:
            import duckdb

            con = duckdb.connect(str(path), read_only=True)
            try:
                return con.execute("SELECT view_name, sql FROM duckdb_views() WHERE NOT internal AND "
                                   "view_name <> '_catalog' ORDER BY view_name").fetchall()
            finally:
                con.close()

        def fast():
            return views(catalog.build_catalog(root))

        def fresh_types(schema: TableSchema) -> list[str]:
            import duckdb

            con = duckdb.connect()
            try:
                return [str(t) for t in con.from_arrow(schema.arrow.empty_table()).types]
            finally:
                con.close()

        def baseline():
            # what every build did before: a new DuckDB connection per contract to learn its column types
            cached, catalog._duckdb_types = catalog._duckdb_types, fresh_types
            try:
                return views(catalog.build_catalog(root))
            finally:
                catalog._duckdb_types = cached

        return fast, baseline

    def same_views(a, b):
        assert a == b, "the catalog's views differ"

    return [
        BenchCase("warehouse", "validate+atomic write, 21x3 keypoints", rows, "rows",
                  "per-row Python lists -> pyarrow -> Parquet, no validation", setup),
        BenchCase("warehouse", "catalog rebuild (a view per contract)", len(registry()), "views",
                  "the same build with a new DuckDB connection per contract for its column types", catalog_setup,
                  check=same_views),
    ]
