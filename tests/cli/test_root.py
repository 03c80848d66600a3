"""User errors are one line without a traceback, at the CLI and in Prefect's logs; crashes are not."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.lib.errors import UserError, is_user_error
from demoforge.lib.takes import TakeError
from tests.support.paths import REPO_ROOT

PROJECT = REPO_ROOT
runner = CliRunner()


def _raised(fn):
    try:
        fn()
    except Exception as e:  # noqa: BLE001
        return e
    raise AssertionError("did not raise")


def test_which_errors_are_the_users():
    from demoforge.flows.augment import retrieve
    from demoforge.lib.llm import LLMError

    assert is_user_error(TakeError("camera.json: bad"))
    assert is_user_error(LLMError("server down"))
    # a ValueError raised by an argument check of flows/ is the user's ...
    assert is_user_error(_raised(lambda: retrieve("/nowhere", "no_such_task", np.zeros((11, 3)))))
    # ... one raised inside numpy (or any library) is a crash, and so is anything else
    assert not is_user_error(_raised(lambda: np.zeros(3).reshape(2, 2)))
    assert not is_user_error(KeyError("x")) and not is_user_error(ValueError("no traceback"))
    assert issubclass(TakeError, UserError) and issubclass(UserError, ValueError)


def test_a_user_error_from_any_command_is_one_line_exit_2(warehouse, monkeypatch):
    import demoforge.schemas.catalog

    def broken(root=None):
        raise TakeError("/data/take/camera.json: camera.json is missing; write it with K")

    monkeypatch.setattr(demoforge.schemas.catalog, "build_catalog", broken)  # `catalog` has no handler of its own
    r = runner.invoke(app, ["catalog"])
    assert r.exit_code == 2 and r.stderr == "error: /data/take/camera.json: camera.json is missing; write it with K\n"


def test_a_crash_is_summarised_with_the_debug_hint_and_debug_shows_it(warehouse, monkeypatch):
    import demoforge.schemas.catalog
    from demoforge.cli import State
    from demoforge.lib.errors import Reporting

    # --debug switches process-wide settings (one command per process); restore them for later tests
    monkeypatch.setattr(Reporting, "show_tracebacks", False)
    monkeypatch.setattr(State, "debug", False)

    def broken(root=None):
        return {}["no such key"]

    monkeypatch.setattr(demoforge.schemas.catalog, "build_catalog", broken)
    r = runner.invoke(app, ["catalog"])
    assert r.exit_code == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "KeyError" in lines[0] and "--debug" in lines[0] and Path(__file__).name in lines[0]
    r = runner.invoke(app, ["--debug", "catalog"])
    assert r.exit_code == 1 and isinstance(r.exception, KeyError)  # raised on, for the full traceback


def test_prefect_logs_a_user_error_without_traceback_and_a_crash_with_one(prefect_api, tmp_path, caplog):
    from prefect import flow

    from demoforge.flows.ingest import ingest_take

    take = tmp_path / "take"
    take.mkdir()
    (take / "camera.json").write_text("{not json")
    with caplog.at_level(logging.ERROR):
        with pytest.raises(TakeError, match="fix the syntax"):
            ingest_take(str(take), str(tmp_path / "warehouse"))
    ours = [r for r in caplog.records if r.name.startswith("prefect.flow_runs") and "camera.json" in r.getMessage()]
    assert ours and all(r.exc_info is None for r in ours)
    assert all("\n" not in r.getMessage() for r in ours)

    @flow(name="crash-for-test")
    def crash():
        return {}["no such key"]

    caplog.clear()
    with caplog.at_level(logging.ERROR):
        with pytest.raises(KeyError):
            crash()
    assert any(r.exc_info is not None for r in caplog.records if r.name.startswith("prefect.flow_runs"))


def test_console_shows_one_line_for_a_bad_camera_json(prefect_api, tmp_path):
    """The issue's case: a malformed camera.json printed Prefect's 20-line traceback before the error."""
    from prefect.settings import get_current_settings

    take = tmp_path / "take"
    take.mkdir()
    (take / "camera.json").write_text("{not json")
    env = {**os.environ, "PREFECT_API_URL": get_current_settings().api.url,
           "DEMOFORGE_WAREHOUSE": str(tmp_path / "warehouse")}
    p = subprocess.run([sys.executable, "-m", "demoforge.cli", "ingest", str(take)], cwd=PROJECT, env=env,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2
    assert p.stderr.splitlines() == [f"error: {take / 'camera.json'}: camera.json is not valid JSON (Expecting "
                                     "property name enclosed in double quotes: line 1 column 2 (char 1)); fix "
                                     "the syntax of the file"]


def test_usage_errors_stay_clicks_own(warehouse):
    r = runner.invoke(app, ["sql", "SELECT 1", "--no-such-option"])
    assert r.exit_code == 2 and "No such option" in r.stderr and "crashed" not in r.stderr
    r = runner.invoke(app, ["sql", "SELECT 1", "--max-rows", "many"])
    assert r.exit_code == 2 and "crashed" not in r.stderr


def test_output_into_a_closed_pipe_ends_quietly(tmp_path):
    """`demoforge sql ... | head -1`: once the reader has gone, writing to stdout fails (EPIPE). That is
    no crash of demoforge: no "crashed ... this is a bug" report, exit code 1 as Click's own commands."""
    for args in (["sql", "SELECT * FROM range(200000)", "--format", "csv"], ["tables"]):
        read_end, write_end = os.pipe()
        os.close(read_end)  # the reader is gone before demoforge writes its first byte
        try:
            p = subprocess.run([sys.executable, "-m", "demoforge.cli", *args], cwd=PROJECT, stdout=write_end,
                               stderr=subprocess.PIPE, text=True, timeout=120,
                               env={**os.environ, "DEMOFORGE_WAREHOUSE": str(tmp_path / "warehouse")})
        finally:
            os.close(write_end)
        assert (p.returncode, p.stderr) == (1, ""), (args, p.stderr)


def test_a_mistyped_path_is_reported_before_the_flow_modules_load(tmp_path):
    """`ingest`, `augment` and `ingest-folder` check their path first: the one-line error comes before
    Prefect and the flows are imported (about 2 s of CPU per command), not after."""
    probe = ("import sys\nfrom demoforge.cli import main\nsys.argv = ['demoforge'] + sys.argv[1:]\n"
             "try:\n    main()\nexcept SystemExit as e:\n    code = e.code\n"
             "print(code, 'prefect' in sys.modules, 'demoforge.flows' in sys.modules)")
    for args in (["ingest", str(tmp_path / "nowhere")], ["augment", str(tmp_path / "nowhere")],
                 ["ingest-folder", str(tmp_path / "nowhere")]):
        p = subprocess.run([sys.executable, "-c", probe, *args], cwd=PROJECT, capture_output=True, text=True,
                           timeout=120, env={**os.environ, "DEMOFORGE_WAREHOUSE": str(tmp_path / "warehouse")})
        assert p.stdout.split() == ["2", "False", "False"], (args, p.stdout, p.stderr)
        assert "no such" in p.stderr and str(tmp_path / "nowhere") in p.stderr
