"""Hold points for tests/flows/test_evaluate.py, loaded by Python at start-up in the `demoforge` processes that
test starts (it puts this folder first on their PYTHONPATH). Without $DEMOFORGE_TEST_HOLD it does nothing.

$DEMOFORGE_TEST_HOLD names where the process parks itself, so the test interrupts it at exactly that
point instead of racing it:
  robot_check       before the first robot check (demoforge.lib.sim.execute_many): the episode database
                    is written, no sim_results yet;
  after_sim_chunk   right after the first `sim_results` file is written.
On reaching it the process writes the point's name to the FIFO $DEMOFORGE_TEST_HOLD_FIFO (the test
blocks reading it) and sleeps until a signal ends it."""

import os

_POINT = os.environ.pop("DEMOFORGE_TEST_HOLD", None)  # popped: processes this one starts do not hold

if _POINT:
    import functools
    import time

    def _hold():
        with open(os.environ["DEMOFORGE_TEST_HOLD_FIFO"], "w") as fifo:
            fifo.write(_POINT)
        while True:
            time.sleep(3600)

    if _POINT == "robot_check":
        import demoforge.lib.sim as _rs

        _execute_many = _rs.execute_many

        @functools.wraps(_execute_many)
        def _held_execute_many(*args, **kwargs):
            _hold()
            return _execute_many(*args, **kwargs)

        _rs.execute_many = _held_execute_many
    elif _POINT == "after_sim_chunk":
        import demoforge.schemas.core as _core

        _write_table = _core.write_table

        @functools.wraps(_write_table)
        def _held_write_table(table, *args, **kwargs):
            written = _write_table(table, *args, **kwargs)
            if table == "sim_results":
                _hold()
            return written

        _core.write_table = _held_write_table
    else:
        raise ValueError(f"unknown DEMOFORGE_TEST_HOLD {_POINT!r}")
