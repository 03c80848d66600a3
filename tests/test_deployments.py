"""The deployments for real: a Prefect server on a free loopback port, `demoforge serve`, and a run
triggered with `prefect deployment run ... --watch` that ingests a folder of takes (one of them bad)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

VENV_BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_healthy(url: str, proc: subprocess.Popen, log: Path, timeout: float = 240) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"prefect server exited ({proc.returncode}):\n{log.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(url + "/health", timeout=5) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        time.sleep(2)
    raise AssertionError(f"prefect server not healthy after {timeout} s:\n{log.read_text()[-3000:]}")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _wait_for_deployments(env: dict, names: list[str], serve: subprocess.Popen, log: Path, timeout: float = 180) -> None:
    deadline = time.time() + timeout
    out = ""
    while time.time() < deadline:
        if serve.poll() is not None:
            raise AssertionError(f"demoforge serve exited ({serve.returncode}):\n{log.read_text()[-3000:]}")
        out = subprocess.run([str(VENV_BIN / "prefect"), "deployment", "ls"], env=env, capture_output=True,
                             text=True, timeout=120).stdout
        if all(n in out for n in names):
            return
        time.sleep(3)
    raise AssertionError(f"deployments {names} not registered:\n{out}\n{log.read_text()[-3000:]}")


def test_served_ingest_deployment_runs_from_the_prefect_cli(tmp_path):
    from lib.synth.take import generate_take
    from schemas.catalog import query

    inbox = tmp_path / "inbox"
    generate_take("trash_in_bin", 0, False, inbox / "synth_trash_in_bin_s0000", video=False, max_frames=12)
    bad = inbox / "broken_take"
    shutil.copytree(inbox / "synth_trash_in_bin_s0000", bad)
    (bad / "camera.json").write_text("{not json")
    warehouse = tmp_path / "warehouse"

    port = _free_port()
    api = f"http://127.0.0.1:{port}/api"
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "prefect_home"), "PREFECT_API_URL": api,
           "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "PREFECT_UI_ENABLED": "false",
           "DEMOFORGE_WAREHOUSE": str(warehouse), "MUJOCO_GL": "egl"}
    env.pop("PREFECT_SERVER_EPHEMERAL_ENABLED", None)
    server_log, serve_log = tmp_path / "server.log", tmp_path / "serve.log"
    server = subprocess.Popen([str(VENV_BIN / "prefect"), "server", "start", "--host", "127.0.0.1", "--port", str(port)],
                              env=env, stdout=server_log.open("w"), stderr=subprocess.STDOUT, cwd=tmp_path)
    serve = None
    try:
        _wait_healthy(api, server, server_log)
        # --every 600: the schedule exists but its next slot is far away; the test triggers a run itself.
        serve = subprocess.Popen([str(VENV_BIN / "demoforge"), "serve", "--inbox", str(tmp_path / "scheduled_inbox"),
                                  "--every", "600", "--reports", str(tmp_path / "reports")],
                                 env=env, stdout=serve_log.open("w"), stderr=subprocess.STDOUT, cwd=tmp_path)
        _wait_for_deployments(env, ["ingest-folder/scheduled", "evaluate/default"], serve, serve_log)
        run = subprocess.run([str(VENV_BIN / "prefect"), "deployment", "run", "ingest-folder/scheduled",
                              "--param", f"folder={inbox}", "--watch", "--watch-timeout", "600"],
                             env=env, capture_output=True, text=True, timeout=700)
        assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:] + serve_log.read_text()[-3000:]
        assert "Completed" in run.stdout
    finally:
        if serve is not None:
            _stop(serve)
        _stop(server)

    got = query("SELECT take, status, error, gripper_rows FROM folder_ingests ORDER BY take", warehouse).to_pylist()
    assert [r["take"] for r in got] == ["broken_take", "synth_trash_in_bin_s0000"]
    broken, good = got
    assert broken["status"] == "failed" and "camera.json" in broken["error"] and broken["gripper_rows"] == 0
    assert good["status"] == "ingested" and good["error"] == ""
    # 12 frames x 2 arms of gripper poses really landed in the warehouse
    n = query("SELECT count(*) AS n FROM gripper_poses WHERE take = 'synth_trash_in_bin_s0000'", warehouse)
    assert n.column("n")[0].as_py() == good["gripper_rows"] == 24
