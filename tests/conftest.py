"""Shared fixtures. Real Prefect (one temporary API server per test session), real DuckDB."""


import shutil
import tempfile

import pytest

import lib  # noqa: F401,E402  (MUJOCO_GL before mujoco)
import tasks  # noqa: F401,E402  (Prefect environment defaults before prefect)

SHARED_DATA = lib.SHARED_DATA

# Free space the suite needs in the temporary directory (synthetic takes, warehouses, videos, model
# weights the tests build): measured peak 1-2 GB (README, Development), plus a margin. A CI run that
# started on a nearly full disk ended with 71 fixture errors; one clear message up front is better.
MIN_FREE_TMP_BYTES = 3 * 1024**3


def pytest_sessionstart(session):
    tmp = tempfile.gettempdir()
    free = shutil.disk_usage(tmp).free
    if free < MIN_FREE_TMP_BYTES:
        pytest.exit(f"only {free / 1024**3:.1f} GiB free in {tmp}; the test suite needs about "
                    f"{MIN_FREE_TMP_BYTES / 1024**3:.0f} GiB there for its synthetic takes and warehouses. "
                    f"Free some space (old pytest-of-* folders, warehouse/ copies) or point TMPDIR at a "
                    f"larger disk, then run `make test` again.", returncode=3)


@pytest.fixture(scope="session")
def prefect_api():
    """A real, temporary Prefect API for flows run by tests (started once per session)."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


@pytest.fixture()
def warehouse(tmp_path, monkeypatch):
    root = tmp_path / "warehouse"
    root.mkdir()
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(root))
    return root


@pytest.fixture(scope="session")
def trash_take(tmp_path_factory):
    """A full synthetic trash_in_bin take (about 240 frames), rendered once per test session."""
    from lib.synth.take import generate_take

    out = tmp_path_factory.mktemp("takes") / "synth_trash_in_bin_s0000"
    generate_take("trash_in_bin", 0, False, out, video=False)
    return out
