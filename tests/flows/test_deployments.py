"""The deployments for real: the session's Prefect server, `demoforge serve`, and a run triggered with
`prefect deployment run ... --watch` that ingests a folder of takes (one of them bad)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

VENV_BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _start_and_wait_for_line(cmd: list[str], env: dict, cwd: Path, log: Path, marker: str) -> subprocess.Popen:
    """Start ``cmd`` and return once it has printed ``marker``: its output is read as it comes (and
    copied to ``log``), so there is no polling and no deadline of our own (pytest-timeout bounds the
    test); if the process ends without printing it, fail with its output."""
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    woke = threading.Event()  # set when the marker is printed, or when the output ends
    seen = []

    def pump():
        with log.open("w") as fh:
            for line in proc.stdout:
                fh.write(line)
                fh.flush()
                if marker in line and not seen:
                    seen.append(line)
                    woke.set()
        woke.set()

    threading.Thread(target=pump, daemon=True).start()
    woke.wait()
    if not seen:
        proc.wait()
        raise AssertionError(f"{cmd[0]} exited ({proc.returncode}) before printing {marker!r}:\n{log.read_text()[-3000:]}")
    return proc


def test_served_ingest_deployment_runs_from_the_prefect_cli(tmp_path, prefect_api_env):
    from demoforge.lib.synth.take import generate_take
    from demoforge.schemas.catalog import query

    inbox = tmp_path / "inbox"
    generate_take("trash_in_bin", 0, False, inbox / "synth_trash_in_bin_s0000", video=False, max_frames=12)
    bad = inbox / "broken_take"
    shutil.copytree(inbox / "synth_trash_in_bin_s0000", bad)
    (bad / "camera.json").write_text("{not json")
    warehouse = tmp_path / "warehouse"

    env = {**os.environ, **prefect_api_env, "PREFECT_HOME": str(tmp_path / "prefect_home"),
           "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "PREFECT_UI_ENABLED": "false",
           "DEMOFORGE_WAREHOUSE": str(warehouse), "MUJOCO_GL": "egl"}
    env.pop("PREFECT_SERVER_EPHEMERAL_ENABLED", None)
    serve_log = tmp_path / "serve.log"
    # --every 600: the schedule exists but its next slot is far away; the test triggers a run itself.
    # prefect.serve prints "... being served ..." once both deployments are registered with the API.
    serve = _start_and_wait_for_line(
        [str(VENV_BIN / "demoforge"), "serve", "--inbox", str(tmp_path / "scheduled_inbox"), "--every", "600",
         "--reports", str(tmp_path / "reports")], env, tmp_path, serve_log, "being served")
    try:
        run = subprocess.run([str(VENV_BIN / "prefect"), "deployment", "run", "ingest-folder/scheduled",
                              "--param", f"folder={inbox}", "--watch", "--watch-timeout", "600"],
                             env=env, capture_output=True, text=True, timeout=700)
        assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:] + serve_log.read_text()[-3000:]
        assert "Completed" in run.stdout
    finally:
        _stop(serve)
    assert "ingest-folder/scheduled" in serve_log.read_text() and "evaluate/default" in serve_log.read_text()

    got = query("SELECT take, status, error, gripper_rows FROM folder_ingests ORDER BY take", warehouse).to_pylist()
    assert [r["take"] for r in got] == ["broken_take", "synth_trash_in_bin_s0000"]
    broken, good = got
    assert broken["status"] == "failed" and "camera.json" in broken["error"] and broken["gripper_rows"] == 0
    assert good["status"] == "ingested" and good["error"] == ""
    # 12 frames x 2 arms of gripper poses really landed in the warehouse
    n = query("SELECT count(*) AS n FROM gripper_poses WHERE take = 'synth_trash_in_bin_s0000'", warehouse)
    assert n.column("n")[0].as_py() == good["gripper_rows"] == 24
