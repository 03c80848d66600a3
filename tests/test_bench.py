"""`make bench` machinery: cases are checked against their baseline and land in `benchmarks`."""

import numpy as np
import pytest

from flows.bench import CASE_FACTORIES, run_benchmarks
from lib.benchmarking import BenchCase, run_case
from schemas.catalog import query


def test_run_case_times_both_and_checks_agreement():
    def setup(n):
        a = np.arange(n, dtype=float)
        return (lambda: a * 2.0), (lambda: np.array([x * 2.0 for x in a]))

    def check(fast, base):
        np.testing.assert_array_equal(fast, base)

    r = run_case(BenchCase("t", "double", 10_000, "items", "python loop", setup, check, repeats=2))
    assert r.seconds > 0 and r.baseline_seconds > 0 and r.ratio == r.baseline_seconds / r.seconds


def test_run_case_refuses_a_fast_path_that_disagrees_with_its_baseline():
    def setup(n):
        return (lambda: np.zeros(n)), (lambda: np.ones(n))

    def check(fast, base):
        np.testing.assert_array_equal(fast, base)

    with pytest.raises(AssertionError):
        run_case(BenchCase("t", "wrong", 100, "items", "ones", setup, check, repeats=1))


def test_scaled_baseline_on_fewer_items():
    def setup(n):
        return (lambda: sum(range(n))), (lambda: sum(range(n)))

    r = run_case(BenchCase("t", "scaled", 100_000, "items", "same", setup, None, repeats=1, baseline_size=10_000))
    assert r.baseline_seconds > 0


def test_bench_flow_writes_rows_queryable_in_sql(prefect_api, warehouse):
    rows = run_benchmarks(str(warehouse), stages=["warehouse"], quick=True)
    assert len(rows) == len(CASE_FACTORIES["warehouse"](True)) >= 1
    t = query("SELECT stage, case_name, ratio, machine FROM benchmarks")
    assert t.num_rows == len(rows)
    assert all(x > 0 for x in t.column("ratio").to_pylist())
    with pytest.raises(ValueError, match="unknown benchmark stage"):
        run_benchmarks(str(warehouse), stages=["nope"], quick=True)
