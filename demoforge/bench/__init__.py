"""Benchmarks: every stage timed against a straightforward baseline in the same run (`make bench`).

:mod:`demoforge.bench.timing` times a case and checks that both sides agree; the `cases_*` modules
hold the larger stages' cases; :mod:`demoforge.bench.run` registers every stage's cases and writes
the `benchmarks` table. Outside the domain library: nothing in demoforge.lib imports this package.
"""
