"""Shared fixtures. Real Prefect (one temporary API server per test session), real DuckDB."""


import pytest

import lib  # noqa: F401,E402  (MUJOCO_GL before mujoco)
import tasks  # noqa: F401,E402  (Prefect environment defaults before prefect)

SHARED_DATA = lib.SHARED_DATA


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
