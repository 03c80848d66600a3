"""The bench flow (demoforge.bench.run): an unknown stage is refused and writes nothing."""

import pytest

from demoforge.bench.run import run_benchmarks


def test_bench_flow_refuses_an_unknown_stage(prefect_api, warehouse):
    """(The warehouse stage's rows, written and queried through `demoforge bench`, are
    tests/cli/test_cli.py::test_tables_catalog_sql_and_bench's.)"""
    with pytest.raises(ValueError, match="unknown benchmark stage"):
        run_benchmarks(str(warehouse), stages=["nope"], quick=True)
    assert not (warehouse / "benchmarks").exists()
