"""The benchmark stages, in the order `make bench` runs them, and the module holding each one's cases.

Every ``cases_<name>.py`` has ``cases(quick) -> list[BenchCase]``; a stage takes the cases of its module
whose ``stage`` is its name (augmentation and retrieval share one module). A new stage: a module with
``cases`` and a line here (demoforge/cli/benchmarks.py lists the names for ``--help``).
"""

from __future__ import annotations

import importlib
from functools import partial
from typing import Callable

from demoforge.bench.timing import BenchCase

CASE_MODULES: dict[str, str] = {
    "warehouse": "cases_warehouse",
    "geometry": "cases_geometry",
    "synth": "cases_synth",
    "ingest": "cases_ingest",
    "augmentation": "cases_augmentation",
    "retrieval": "cases_augmentation",
    "sim": "cases_sim",
    "arms": "cases_arms",
    "detection": "cases_detection",
    "hamer": "cases_hamer",
    "takes": "cases_takes",
    "exports": "cases_exports",
    "policy": "cases_policy",
    "llm": "cases_llm",
}


def cases_for(stage: str, quick: bool) -> list[BenchCase]:
    """The cases of one stage (quick: the smaller sizes of `make bench-quick` and the tests)."""
    module = importlib.import_module(f"demoforge.bench.{CASE_MODULES[stage]}")
    return [c for c in module.cases(quick) if c.stage == stage]


#: stage -> quick -> its cases
CASE_FACTORIES: dict[str, Callable[[bool], list[BenchCase]]] = {s: partial(cases_for, s) for s in CASE_MODULES}
