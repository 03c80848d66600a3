"""Robustness of the main job: interrupt `demoforge evaluate` with SIGINT, then kill it with SIGKILL
(the whole process group, as a crash would), run it again: it resumes, does not redo finished stages,
and its tables equal those of an uninterrupted run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow as pa
import pytest

VENV_BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow

ARGS = ["evaluate", "--task", "trash_in_bin", "--mirror", "no", "--episodes", "60", "--sim-episodes", "4",
        "--trials", "0"]
TABLES = ("takes", "frames", "hand_keypoints", "aligned_keypoints", "gripper_poses", "object_keypoints",
          "ingest_metrics", "segments", "episodes", "episode_steps", "sim_results", "keypoint_metrics")
VOLATILE = {"wall_s", "generate_seconds", "replay_seconds"}  # wall-clock timings


def _env(tmp_path: Path, warehouse: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DEMOFORGE_")}
    return {**env, "DEMOFORGE_WAREHOUSE": str(warehouse), "PREFECT_HOME": str(tmp_path / "prefect_home"),
            "MUJOCO_GL": "egl"}


def _start(env: dict, cwd: Path, log: Path) -> subprocess.Popen:
    # a session of its own: the signal reaches demoforge and every child (Prefect's temporary
    # server, simulation workers), like Ctrl-C in a terminal or a machine going down
    # SIGINT back to its default: a shell that starts a command in the background (CI, `cmd &`) makes it
    # ignore SIGINT, and an ignored signal stays ignored across exec, so Python would never see Ctrl-C
    return subprocess.Popen([str(VENV_BIN / "demoforge"), *ARGS], env=env, cwd=cwd, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=log.open("a"), stderr=subprocess.STDOUT)


def _wait_for(path_glob: str, root: Path, proc: subprocess.Popen, log: Path, timeout: float = 900) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if any(root.glob(path_glob)):
            return
        if proc.poll() is not None:
            raise AssertionError(f"evaluate ended ({proc.returncode}) before {path_glob} appeared:\n"
                                 f"{log.read_text()[-3000:]}")
        time.sleep(0.5)
    raise AssertionError(f"{path_glob} did not appear within {timeout} s")


def _finish(env: dict, cwd: Path, log: Path) -> str:
    r = subprocess.run([str(VENV_BIN / "demoforge"), *ARGS], env=env, cwd=cwd, capture_output=True, text=True,
                       timeout=1800)
    log.open("a").write(r.stdout + r.stderr)
    assert r.returncode == 0, f"evaluate failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    return r.stdout


def _same_rows(a: pa.Table, b: pa.Table, root_a: Path, root_b: Path) -> bool:
    """Equal schemas and values, NaN equal to NaN, each warehouse's own path replaced by a placeholder
    (the `takes` table records where the take folder is)."""
    def canon(t: pa.Table, root: Path) -> str:
        return json.dumps(t.to_pylist(), default=str).replace(str(root), "<warehouse>")

    return a.schema == b.schema and canon(a, root_a) == canon(b, root_b)


def _table(warehouse: Path, name: str) -> pa.Table:
    from schemas.core import read_table

    t = read_table(name, warehouse)
    t = t.drop_columns([c for c in t.column_names if c in VOLATILE])
    # rows in a canonical order: sorted by every scalar column
    keys = [f.name for f in t.schema if not (pa.types.is_list(f.type) or pa.types.is_fixed_size_list(f.type)
                                              or pa.types.is_struct(f.type))]
    return t.sort_by([(k, "ascending") for k in keys])


def test_evaluate_resumes_after_sigint_and_sigkill_and_equals_an_uninterrupted_run(tmp_path):
    from tests.conftest import SHARED_DATA, require_mediapipe_model

    if (SHARED_DATA / "real_hands").is_dir():  # the main job runs the MediaPipe detector on the photos
        require_mediapipe_model()
    ref, crashed = tmp_path / "reference", tmp_path / "crashed"
    log = tmp_path / "evaluate.log"
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    _finish(_env(tmp_path, ref), tmp_path / "a", log)

    env = _env(tmp_path, crashed)
    # 1) Ctrl-C once the episode database is written (the robot checks have not run yet)
    proc = _start(env, tmp_path / "b", log)
    _wait_for("episodes/**/data.parquet", crashed, proc, log)
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(120) != 0
    # stages that had certainly finished: the take and its ingest (the augmentation stage, running
    # when the signal came, may have written episodes without finishing: it is allowed to rerun)
    finished = [next(crashed.glob("synthetic/*/camera.json"))] + \
        [next(crashed.glob(f"{t}/**/data.parquet")) for t in ("frames", "hand_keypoints", "gripper_poses")]
    stamps = [f.stat().st_mtime_ns for f in finished]

    # 2) SIGKILL everything as soon as the first robot-check chunk is on disk
    proc = _start(env, tmp_path / "b", log)
    _wait_for("sim_results/**/data.parquet", crashed, proc, log)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(60)

    # 3) run again to the end
    assert "nothing changed" not in _finish(env, tmp_path / "b", log)
    assert (tmp_path / "b" / "reports" / "REPORT.md").is_file()
    # finished stages were not redone: the take was not re-rendered, not re-ingested
    assert [f.stat().st_mtime_ns for f in finished] == stamps
    episodes_file = next(crashed.glob("episodes/**/data.parquet"))
    episodes_stamp = episodes_file.stat().st_mtime_ns
    # no temporary files of interrupted writes are visible
    assert not [p for p in crashed.rglob("*") if p.is_file() and ".tmp" in p.name and "_prefect" not in p.parts]
    for name in TABLES:
        a, b = _table(ref, name), _table(crashed, name)
        assert a.num_rows > 0, name
        assert _same_rows(a, b, ref, crashed), f"{name}: the resumed run's rows differ from the uninterrupted run"

    # 4) a second run with nothing changed returns from the run-level cache; deleting a table file
    # makes the next run notice it and recompute exactly that file
    assert "nothing changed since the last complete run" in _finish(env, tmp_path / "b", log)
    chunk = next(crashed.glob("sim_results/**/data.parquet"))
    chunk.unlink()
    assert "nothing changed" not in _finish(env, tmp_path / "b", log)
    assert chunk.is_file() and episodes_file.stat().st_mtime_ns == episodes_stamp
    assert _same_rows(_table(ref, "sim_results"), _table(crashed, "sim_results"), ref, crashed)
