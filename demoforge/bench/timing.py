"""Benchmark harness: time an optimised stage against a straightforward baseline in the same run.

A case is a function ``setup(size) -> (fast, baseline)`` returning two zero-argument callables on
the same prepared input. The harness checks they agree (via an optional ``check``), times each with
best-of-``repeats``, and reports the ratio baseline/fast. No thresholds: figures are reported, not
asserted.
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class BenchCase:
    stage: str
    name: str
    size: int
    unit: str
    baseline: str  # what the baseline is, in words
    setup: Callable[[int], tuple[Callable[[], Any], Callable[[], Any]]]
    check: Callable[[Any, Any], None] | None = None
    repeats: int = 3
    baseline_size: int | None = None  # a slow baseline may run on fewer items; time is scaled up


@dataclass(frozen=True)
class BenchResult:
    stage: str
    case: str
    size: int
    unit: str
    seconds: float
    baseline_seconds: float
    baseline: str
    repeats: int

    @property
    def ratio(self) -> float:
        return self.baseline_seconds / self.seconds if self.seconds > 0 else float("inf")

    @property
    def items_per_second(self) -> float:
        return self.size / self.seconds if self.seconds > 0 else float("inf")


@contextmanager
def one_core():
    """Run the block on one core of those this process may use (every thread of it, BLAS's included: a case
    measured "on one core" is not helped by a library's threads), then on all of them again."""
    allowed = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if allowed:
        os.sched_setaffinity(0, {min(allowed)})
    try:
        yield
    finally:
        if allowed:
            os.sched_setaffinity(0, allowed)


def best_time(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    best, out = float("inf"), None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def run_case(case: BenchCase) -> BenchResult:
    fast, _ = case.setup(case.size)
    seconds, fast_out = best_time(fast, case.repeats)
    bsize = case.baseline_size or case.size
    _, baseline = case.setup(bsize)
    baseline_seconds, base_out = best_time(baseline, case.repeats)
    if case.check is not None and bsize == case.size:
        case.check(fast_out, base_out)
    if bsize != case.size:
        # The baseline is linear in the item count; measure it on fewer items and scale.
        baseline_seconds *= case.size / bsize
        if case.check is not None:
            small_fast, small_base = case.setup(bsize)
            case.check(small_fast(), small_base())
    return BenchResult(case.stage, case.name, case.size, case.unit, seconds, baseline_seconds,
                       case.baseline, case.repeats)
