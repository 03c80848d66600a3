"""Every `demoforge` command's main path on a tiny take: exit code 0 and one table or file it writes.

Deeper checks of each stage live in the flow tests; these catch a command whose wiring (options,
defaults, the flow it calls, what it prints) broke. Commands run in-process (typer's CliRunner)
against the session's Prefect API."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from demoforge.cli import app
from demoforge.schemas.catalog import query
from tests.support.mediapipe_model import require_mediapipe_model


def _run(*args: str):
    r = CliRunner().invoke(app, list(args))
    assert r.exit_code == 0, f"demoforge {' '.join(args)} -> {r.exit_code}:\n{r.output[-3000:]}\n{r.exception!r}"
    return r


def _count(table: str, warehouse, where: str = "true") -> int:
    return query(f"SELECT count(*) AS n FROM {table} WHERE {where}", warehouse).column("n")[0].as_py()


def test_synth_then_ingest_folder(prefect_api, warehouse, tmp_path):
    inbox = tmp_path / "inbox"
    r = _run("synth", "--task", "pouring", "--takes", "1", "--max-frames", "6", "--no-video", "--out", str(inbox))
    take = inbox / "synth_pouring_s0000"
    assert str(take) in r.output and (take / "camera.json").is_file() and len(list((take / "rgb").glob("*.png"))) == 6
    assert query("SELECT take, task, n_frames FROM takes", warehouse).to_pylist() == [
        {"take": "synth_pouring_s0000", "task": "pouring", "n_frames": 6}]
    assert _count("gt_hand_joints", warehouse) == 12

    _run("ingest-folder", str(inbox))
    rows = query("SELECT take, status, gripper_rows FROM folder_ingests", warehouse).to_pylist()
    assert rows == [{"take": "synth_pouring_s0000", "status": "ingested", "gripper_rows": 12}]
    assert _count("gripper_poses", warehouse, "take = 'synth_pouring_s0000'") == 12

    # evaluate-detection on the synthesized take: MediaPipe (the real detector) in image mode
    require_mediapipe_model()
    r = _run("evaluate-detection", "--mode", "image", "--take", "synth_pouring_s0000")
    got = query("SELECT take, running_mode, subset, frames FROM detection_metrics ORDER BY subset", warehouse).to_pylist()
    assert [(g["take"], g["running_mode"], g["frames"]) for g in got] == [("synth_pouring_s0000", "image", 6)] * len(got)
    assert {g["subset"] for g in got} >= {"all"} and "pouring" in r.output  # the per-task table, printed


def test_commands_on_an_episode_database(prefect_api, ingested_warehouse, trash_take, tmp_path):
    """augment -> llm-eval (the LLM-free strategies) -> variations (default strategies, the spatial kind)
    -> render-episode, on trash_take's ingest."""
    wh = ingested_warehouse
    r = _run("augment", str(trash_take), "-n", "20", "--mirrored", "10")
    assert _count("episodes", wh) == 21  # the original, 10 translated, 10 mirrored
    # the demonstration every episode comes from, executed by the robot and said in one line
    assert "robot check of the ingested demonstration: success: can centre in bin frame" in r.output
    assert query("SELECT success FROM ingested_demo_checks WHERE take = ?", wh, [trash_take.name]).to_pylist() == [
        {"success": True}]

    r = _run("llm-eval", "--task", "trash_in_bin", "--strategy", "replay_top1", "--strategy", "transform_demo",
             "--trials", "1")
    trials = query("SELECT strategy, backend, sim_detail FROM llm_trials ORDER BY strategy", wh).to_pylist()
    assert [(t["strategy"], t["backend"]) for t in trials] == [("replay_top1", "none"), ("transform_demo", "none")]
    assert all(t["sim_detail"] for t in trials) and "replay_top1" in r.output  # report_table3 printed

    r = _run("variations", "--task", "trash_in_bin", "--kind", "spatial", "--trials", "1")
    v = query("SELECT variation, strategy, detail FROM variation_trials ORDER BY strategy", wh).to_pylist()
    assert [(x["variation"], x["strategy"]) for x in v] == [("spatial", "replay_top1"), ("spatial", "transform_demo")]
    assert all(x["detail"] for x in v) and "transform_demo" in r.output  # report_table4 printed

    # retrieve: a scene whose keypoints are one episode's comes back with that episode first, at MSE 0
    ep = query("SELECT episode_id, object_keypoints FROM episodes WHERE valid AND kind = 'mirrored' ORDER BY episode_id "
               "LIMIT 1", wh).to_pylist()[0]
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"object_keypoints": ep["object_keypoints"]}))
    r = _run("retrieve", "--task", "trash_in_bin", "--scene", str(scene), "-k", "2", "--format", "json")
    got = [json.loads(line) for line in r.output.splitlines()]
    assert len(got) == 2 and got[0]["episode_id"] == ep["episode_id"] and got[0]["mse"] == 0.0 < got[1]["mse"], got
    r = _run("retrieve", "--task", "trash_in_bin", "--scene", str(scene), "--strategy", "single", "-f", "json")
    assert [json.loads(line)["episode_id"] for line in r.output.splitlines()] == [0]  # the original demonstration

    out = tmp_path / "ep0.mp4"
    r = _run("render-episode", "--task", "trash_in_bin", "--episode", "0", "--out", str(out))
    assert out.stat().st_size > 10_000 and str(out) in r.output


def test_tables_catalog_sql_and_bench(prefect_api, warehouse):
    from demoforge.bench.registry import CASE_FACTORIES

    r = _run("bench", "--stage", "warehouse", "--quick")
    rows = query("SELECT stage, case_name, seconds, baseline_seconds, ratio FROM benchmarks", warehouse).to_pylist()
    n = len(CASE_FACTORIES["warehouse"](True))
    assert len(rows) == n >= 1 and all(row["stage"] == "warehouse" and row["case_name"][:30] in r.output for row in rows)
    # each row as the command printed it: its seconds, the baseline's and their ratio
    for row in rows:
        line = next(ln for ln in r.stdout.splitlines() if ln.startswith("warehouse") and row["case_name"][:30] in ln).split()
        assert [float(x) for x in line[-3:-1]] == [round(row["seconds"], 4), round(row["baseline_seconds"], 4)]
        assert row["ratio"] == pytest.approx(row["baseline_seconds"] / row["seconds"])

    r = _run("catalog")
    assert (warehouse / "catalog.duckdb").is_file() and "catalog rebuilt" in r.output
    import duckdb

    con = duckdb.connect(str(warehouse / "catalog.duckdb"), read_only=True)
    try:
        assert "benchmarks" in {row[0] for row in con.execute("SELECT view_name FROM duckdb_views()").fetchall()}
    finally:
        con.close()

    listing = _run("tables").output
    line = next(ln for ln in listing.splitlines() if ln.split() and ln.split()[0] == "benchmarks")
    assert str(n) in line.split()[1:]  # one row per case
    described = _run("tables", "benchmarks").output
    assert "case_name" in described and "ratio" in described

    out = json.loads(_run("sql", "SELECT count(*) AS n FROM benchmarks", "-f", "json").output)
    assert out == {"n": n}


def test_augment_warns_on_stderr_when_the_robot_fails_the_demonstration_itself(tmp_path, capsys):
    import pyarrow as pa

    from demoforge.cli.pipeline import _say_demo_check
    from demoforge.schemas.core import write_table
    from demoforge.tasks.common import Manifest

    row = {"task": "pouring", "take": "my_take", "detector": "mediapipe", "status": "executed", "success": False,
           "failure": "table_collision", "detail": "arm 1 pushes on the table with 65 N at t = 1.13 s",
           "frames": 359, "wall_s": 0.04, "valid_left": 0.5, "valid_right": 0.9, "trusted_hands": 2}
    written = write_table("ingested_demo_checks", pa.Table.from_pylist([row]), tmp_path / "wh")
    _say_demo_check(Manifest.from_written("ingested_demo_checks", written), tmp_path / "my_take")
    out = capsys.readouterr()
    assert out.out == "" and out.err.startswith("warning: the robot fails the ingested demonstration itself: "
                                                "table_collision (arm 1 pushes on the table")
    assert "every episode of this database is built from it" in out.err and out.err.count("\n") == 1
