"""The main job end to end, and its robustness: `demoforge evaluate` on one task writes the report with
every section; interrupted with SIGINT, then killed with SIGKILL (the whole process group, as a crash
would), and run again, it resumes, does not redo finished stages, and its tables equal those of an
uninterrupted run; a run with nothing changed returns from the cache."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import psutil
import pyarrow as pa
import pytest
from tests.support.paths import HOLD_POINTS
from tests.support.tables import canonical_table

VENV_BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow

# every stage of the main job on one task, each at the smallest size that still runs it (the stability
# check and the Table 4 analogue at their defaults were 54 of the 58 robot executions of each full run)
# (robots: the floating grippers and the arms with the 2F-140; the arms with ALOHA's own fingers take the
# same code path, and tests/lib/sim/robots/aloha/test_aloha.py executes them)
ARGS = ["evaluate", "--task", "trash_in_bin", "--mirror", "no", "--episodes", "60", "--sim-episodes", "4",
        "--stability-episodes", "2", "--stability-repeats", "2", "--variation-trials", "1", "--trials", "0",
        "--robot", "grippers", "--robot", "aloha+2f140"]
TABLES = ("takes", "frames", "hand_keypoints", "aligned_keypoints", "gripper_poses", "object_keypoints",
          "ingest_metrics", "segments", "episodes", "episode_steps", "sim_results", "sim_stability",
          "variation_trials", "keypoint_metrics")
VOLATILE = {"wall_s", "sim_wall_s", "generate_seconds", "replay_seconds"}  # wall-clock timings


def _env(tmp_path: Path, warehouse: Path, api: dict) -> dict:
    """``api``: the session's Prefect API (the uninterrupted runs: no temporary server to start), or {}
    (the interrupted runs: their own temporary server, which must survive Ctrl-C and die with them)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DEMOFORGE_")}
    return {**env, **api, "DEMOFORGE_WAREHOUSE": str(warehouse), "PREFECT_HOME": str(tmp_path / "prefect_home"),
            "MUJOCO_GL": "egl"}


def _start(env: dict, cwd: Path, log: Path, hold: str, fifo: Path) -> subprocess.Popen:
    """Start `demoforge evaluate` parked at the hold point `hold` (tests/support/hold_points), which it announces
    on the FIFO `fifo`."""
    os.mkfifo(fifo)
    env = {**env, "DEMOFORGE_TEST_HOLD": hold, "DEMOFORGE_TEST_HOLD_FIFO": str(fifo),
           "PYTHONPATH": os.pathsep.join([str(HOLD_POINTS)] + [p for p in [env.get("PYTHONPATH")] if p])}
    # a session of its own: the signal reaches demoforge and every child (Prefect's temporary server,
    # simulation workers), like Ctrl-C in a terminal or a machine going down
    # SIGINT back to its default: a shell that starts a command in the background (CI, `cmd &`) makes it
    # ignore SIGINT, and an ignored signal stays ignored across exec, so Python would never see Ctrl-C
    return subprocess.Popen([str(VENV_BIN / "demoforge"), *ARGS], env=env, cwd=cwd, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=log.open("a"), stderr=subprocess.STDOUT)


def _wait_for_hold(fifo: Path, proc: subprocess.Popen, log: Path, hold: str) -> None:
    """Block until the process is parked at its hold point (it writes the point's name to the FIFO), or
    has ended without reaching it (a watcher thread then writes 'exited'): no polling, no race."""
    def on_exit():
        proc.wait()
        with open(fifo, "w") as f:  # wakes the reader below if the process never got there
            f.write("exited")

    threading.Thread(target=on_exit, daemon=True).start()
    with open(fifo) as f:
        got = f.read()
    if got != hold:
        raise AssertionError(f"evaluate ended ({proc.returncode}) before its hold point {hold}:\n{log.read_text()[-3000:]}")


def _own_servers(prefect_home: Path) -> list:
    """The temporary Prefect API servers that runs with ``prefect_home`` started and that are alive."""
    def ours(p: psutil.Process) -> bool:
        try:
            return "prefect.server.api.server:create_app" in " ".join(p.cmdline()) and \
                p.environ().get("PREFECT_HOME") == str(prefect_home)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            return False

    return [p for p in psutil.process_iter() if ours(p)]


def _finish(env: dict, cwd: Path, log: Path) -> str:
    r = subprocess.run([str(VENV_BIN / "demoforge"), *ARGS], env=env, cwd=cwd, capture_output=True, text=True,
                       timeout=1800)
    log.open("a").write(r.stdout + r.stderr)
    assert r.returncode == 0, f"evaluate failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stdout + r.stderr, r.stderr[-3000:]   # nor from Prefect's own services
    return r.stdout


def _same_rows(a: pa.Table, b: pa.Table, root_a: Path, root_b: Path) -> bool:
    """Equal schemas and values, NaN equal to NaN, each warehouse's own path replaced by a placeholder
    (the `takes` table records where the take folder is)."""
    def canon(t: pa.Table, root: Path) -> str:
        return json.dumps(t.to_pylist(), default=str).replace(str(root), "<warehouse>")

    return a.schema == b.schema and canon(a, root_a) == canon(b, root_b)


def _table(warehouse: Path, name: str) -> pa.Table:
    return canonical_table(warehouse, name, VOLATILE)


def _check_report(reports: Path, have_photos: bool, have_mediapipe: bool) -> None:
    """Every section of REPORT.md, its CSVs and figures, and the detectors side by side."""
    text = (reports / "REPORT.md").read_text()
    for heading in ("## Takes", "## Scripted demonstrations in physics", "## Ingest accuracy per task",
                    "## Segmentation against the scripted boundaries", "## Augmented episodes",
                    "## Table 1: MPJPE and PA-MPJPE (m) — synthetic, by detector",
                    "## Robot success on the ingested demonstrations, per detector",
                    "## Table 2: 2D MPJPE (px) and PCK", "## Appendix B: per take",
                    "## A real detector on labelled real photos", "## How stable the robot check's verdicts are"):
        assert heading in text
    assert "synth_trash_in_bin_s0000" in text and "simulated" in text
    assert "![synthetic takes](synthetic_takes.png)" in text and (reports / "synthetic_takes.png").stat().st_size > 10_000
    assert (reports / "keypoints_per_take_synthetic_simulated.png").stat().st_size > 5_000
    for name in ("report_takes", "report_ingest_accuracy", "report_augmentation", "report_segmentation",
                 "report_table1_synthetic", "report_ingested_demos") + (("report_real_photos",) if have_photos else ()):
        assert len((reports / f"{name}.csv").read_text().splitlines()) >= 2, name
    stability = (reports / "report_sim_stability.csv").read_text().splitlines()
    assert len(stability) == 2 and "sample-2-seed0-r2-j0.0001-s0" in stability[1]
    # the detectors side by side: every table of the ingest's accuracy, Tables 1 and 2, the robot's check
    detectors = ["simulated", "mediapipe"] if have_mediapipe else ["simulated"]
    for name, rows_per_detector in (("report_ingest_by_task", 1), ("report_ingest_accuracy", 2),
                                    ("report_table1_synthetic", 4), ("report_table2_synthetic", 2),
                                    ("report_ingested_demos", 1)):
        found = [r["detector"] for r in csv.DictReader((reports / f"{name}.csv").open())]
        assert sorted(found) == sorted(d for d in detectors for _ in range(rows_per_detector)), (name, found)
    if have_mediapipe:
        assert (reports / "keypoints_per_take_synthetic_mediapipe.png").stat().st_size > 5_000
    aug = (reports / "report_augmentation.csv").read_text()
    assert '"original"' in aug and '"mirrored"' in aug and '"translated"' in aug


def test_evaluate_writes_the_report_resumes_after_sigint_and_sigkill_and_equals_an_uninterrupted_run(
        tmp_path, prefect_api_env):
    from demoforge.flows.evaluate import detector_problem
    from demoforge.lib import SHARED_DATA
    from tests.support.mediapipe_model import require_mediapipe_model

    have_photos = (SHARED_DATA / "real_hands").is_dir()
    if have_photos:  # the main job runs the MediaPipe detector on the photos
        require_mediapipe_model()
    have_mediapipe = detector_problem("mediapipe") is None  # else the main job leaves it out (warned)
    ref, crashed = tmp_path / "reference", tmp_path / "crashed"
    log = tmp_path / "evaluate.log"
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    _finish(_env(tmp_path, ref, prefect_api_env), tmp_path / "a", log)
    _check_report(tmp_path / "a" / "reports", have_photos, have_mediapipe)

    env, own_server = _env(tmp_path, crashed, prefect_api_env), _env(tmp_path, crashed, {})
    # 1) Ctrl-C once the episode database is written, before the first robot check (parked there)
    proc = _start(own_server, tmp_path / "b", log, "robot_check", tmp_path / "hold1")
    _wait_for_hold(tmp_path / "hold1", proc, log, "robot_check")
    assert next(crashed.glob("episodes/**/data.parquet"), None) and not list(crashed.glob("sim_results/**/*.parquet"))
    servers = _own_servers(tmp_path / "prefect_home")
    assert len(servers) == 1  # its own temporary API server, in a session of its own (not signalled)
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(120) != 0
    # ... which went when the run ended (stopped at its exit)
    assert psutil.wait_procs(servers, timeout=30)[1] == [], "the interrupted run left its temporary API server"
    # stages that had finished: the take, its ingest and its episode database
    finished = [next(crashed.glob("synthetic/*/camera.json"))] + \
        [next(f for f in sorted(crashed.glob(f"{t}/**/data.parquet")) if "detector=" not in f.as_posix())
         for t in ("frames", "hand_keypoints", "gripper_poses")]
    # (the default ingest's files: a side-by-side detector's ingest may still be running at the Ctrl-C)
    stamps = [f.stat().st_mtime_ns for f in finished]

    # 2) SIGKILL everything once the first robot-check chunk is on disk (parked right after writing it)
    proc = _start(own_server, tmp_path / "b", log, "after_sim_chunk", tmp_path / "hold2")
    _wait_for_hold(tmp_path / "hold2", proc, log, "after_sim_chunk")
    assert len(list(crashed.glob("sim_results/**/data.parquet"))) == 1
    servers = _own_servers(tmp_path / "prefect_home")
    assert len(servers) == 1
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(60)
    # its temporary server was not in the killed process group, and gets SIGTERM when its parent dies
    assert psutil.wait_procs(servers, timeout=30)[1] == [], "the killed run left its temporary API server"
    # the temporary servers' own output (their services' errors, cut off at Ctrl-C or SIGKILL) went to
    # their log file, not to the command's terminal
    assert (tmp_path / "prefect_home" / "demoforge-temporary-server.log").is_file()
    assert "prefect.server" not in log.read_text() and "docket" not in log.read_text()

    # 3) run again to the end
    assert "nothing changed" not in _finish(env, tmp_path / "b", log)
    assert (tmp_path / "b" / "reports" / "REPORT.md").is_file()
    # finished stages were not redone: the take was not re-rendered, not re-ingested
    assert [f.stat().st_mtime_ns for f in finished] == stamps
    episodes_file = next(crashed.glob("episodes/**/data.parquet"))
    episodes_stamp = episodes_file.stat().st_mtime_ns
    # no temporary files of interrupted writes are visible
    assert not [p for p in crashed.rglob("*") if p.is_file() and ".tmp" in p.name and "_prefect" not in p.parts]
    # the robot's check of MediaPipe's ingested demonstration: where the side-by-side ingest runs
    for name in TABLES + (("ingested_demo_checks",) if have_mediapipe else ()):
        a, b = _table(ref, name), _table(crashed, name)
        assert a.num_rows > 0, name
        assert _same_rows(a, b, ref, crashed), f"{name}: the resumed run's rows differ from the uninterrupted run"

    # 4) a second run with nothing changed returns from the run-level cache, with the same report;
    # deleting a table file makes the next run notice it and recompute exactly that file
    report = tmp_path / "b" / "reports" / "REPORT.md"
    written = report.read_text()
    assert "nothing changed since the last complete run" in _finish(env, tmp_path / "b", log)
    assert report.read_text() == written
    chunk = next(crashed.glob("sim_results/**/data.parquet"))
    chunk.unlink()
    assert "nothing changed" not in _finish(env, tmp_path / "b", log)
    assert chunk.is_file() and episodes_file.stat().st_mtime_ns == episodes_stamp
    assert _same_rows(_table(ref, "sim_results"), _table(crashed, "sim_results"), ref, crashed)
