"""`make bench` machinery (demoforge.bench.timing): cases are checked against their baseline and land in
`benchmarks`; their scratch files go when the process ends. (The flow: test_run.py; the registry: test_registry.py.)"""

import os
import subprocess
import sys

import numpy as np
import pytest

from demoforge.bench.registry import CASE_FACTORIES
from demoforge.bench.timing import BenchCase, run_case
from demoforge.schemas.catalog import query


class FakeClock:
    """time.perf_counter for demoforge.bench.timing: the benchmarked functions advance it by known amounts."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def spend(self, seconds):
        self.now += seconds


@pytest.fixture()
def clock(monkeypatch):
    c = FakeClock()
    monkeypatch.setattr("demoforge.bench.timing.time.perf_counter", c)
    return c


def test_run_case_times_both_and_checks_agreement(clock):
    fast_costs = iter([0.5, 0.2, 0.3])  # best of 3 repeats: 0.2 s
    checked = []

    def setup(n):
        a = np.arange(n, dtype=float)
        return (lambda: clock.spend(next(fast_costs)) or a * 2.0), (lambda: clock.spend(3.0) or np.array([x * 2.0 for x in a]))

    def check(fast, base):
        checked.append(len(fast))
        np.testing.assert_array_equal(fast, base)

    r = run_case(BenchCase("t", "double", 10_000, "items", "python loop", setup, check, repeats=3))
    assert r.seconds == pytest.approx(0.2) and r.baseline_seconds == pytest.approx(3.0)
    assert r.ratio == pytest.approx(15.0) and r.items_per_second == pytest.approx(50_000)
    assert checked == [10_000]


def test_run_case_refuses_a_fast_path_that_disagrees_with_its_baseline():
    def setup(n):
        return (lambda: np.zeros(n)), (lambda: np.ones(n))

    def check(fast, base):
        np.testing.assert_array_equal(fast, base)

    with pytest.raises(AssertionError):
        run_case(BenchCase("t", "wrong", 100, "items", "ones", setup, check, repeats=1))


def test_scaled_baseline_on_fewer_items(clock):
    sizes = []

    def setup(n):
        sizes.append(n)
        return (lambda: clock.spend(2.0) or sum(range(n))), (lambda: clock.spend(1.0) or sum(range(n)))

    checked = []
    r = run_case(BenchCase("t", "scaled", 100_000, "items", "same", setup, lambda f, b: checked.append((f, b)),
                           repeats=1, baseline_size=10_000))
    # the baseline ran on 10,000 items in 1 s: 10 s for the case's 100,000, ratio 10 / 2
    assert r.baseline_seconds == pytest.approx(10.0) and r.ratio == pytest.approx(5.0)
    # fast and baseline are compared on the baseline's size, where both exist
    assert sizes == [100_000, 10_000, 10_000] and checked == [(sum(range(10_000)), sum(range(10_000)))]


def test_the_cases_scratch_files_are_removed_when_the_process_ends(tmp_path):
    scratch = tmp_path / "tmpdir"
    scratch.mkdir()
    code = ("import pathlib, sys; from demoforge.bench.registry import CASE_FACTORIES; "
            "from demoforge.bench.timing import run_case; [run_case(c) for c in CASE_FACTORIES['warehouse'](True)]; "
            "print(sum(p.is_file() for p in pathlib.Path(sys.argv[1]).rglob('*.parquet')))")
    r = subprocess.run([sys.executable, "-c", code, str(scratch)], capture_output=True, text=True,
                       env={**os.environ, "TMPDIR": str(scratch)}, timeout=300)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.split()[-1]) >= 2  # the fast path's and the baseline's tables were written there
    assert list(scratch.iterdir()) == []
