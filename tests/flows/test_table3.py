"""The Table 3 grid (demoforge.flows.table3 and `demoforge table3`) end to end on one take, and the command's bad
options refused in one line."""

import pytest


def test_table3_grid_end_to_end(prefect_api, warehouse, trash_take):
    """One take, two thesis scenes, the LLM-free strategies and a scripted LLM answer: rows for every
    cell, the report views in the thesis's layout, and the nearest episode replayed succeeds."""
    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.flows.table3 import table3
    from demoforge.schemas.catalog import query

    # the command's main path, for the LLM-free strategies: its options reach the flow
    r = CliRunner().invoke(app, ["table3", "--task", "trash_in_bin", "--take-dir", str(trash_take), "--scenes", "2",
                                 "--episodes", "200", "--strategy", "replay_original", "--strategy", "replay_top1",
                                 "--strategy", "knn_blend", "--strategy", "transform_demo"])
    assert r.exit_code == 0, r.output
    assert "Table 3" in r.stdout and "Take1" in r.stdout and "Wilson 95 % intervals" in r.stdout
    db = query("SELECT take, count(*) AS n FROM episodes GROUP BY take", warehouse).to_pylist()
    assert db == [{"take": trash_take.name, "n": 201}]       # the take's database, of --episodes episodes
    # the LLM cells (a scripted answer) beside them: the database comes from the cache
    table3(str(warehouse), task="trash_in_bin", protocols=["thesis"], takes=1, scenes=2, llm_scenes=1,
           strategies=["single", "retrieval"], backend="fake", backend_options={"responses": ["no trajectory here"]},
           episodes=200, take_dirs=[str(trash_take)], show_progress=False)
    rows = query("SELECT * FROM table3_trials ORDER BY strategy, scene", warehouse).to_pylist()
    by = {}
    for r in rows:
        by.setdefault(r["strategy"], []).append(r)
    assert {k: len(v) for k, v in by.items()} == {"single": 1, "retrieval": 1, "replay_original": 2,
                                                   "replay_top1": 2, "knn_blend": 2, "transform_demo": 2}
    # the 3 Retrieved prompt holds the scene's three nearest episodes (those knn_blend blends), and so
    # about three times the one-example prompt
    assert by["retrieval"][0]["example_ids"] == by["knn_blend"][0]["example_ids"]
    assert by["retrieval"][0]["prompt_tokens"] > 2.5 * by["single"][0]["prompt_tokens"]
    assert all(r["protocol"] == "thesis" and r["take_index"] == 1 and r["nearest_mse"] > 0 for r in rows)
    # the scripted LLM answer does not parse: a failed trial, not a crash
    assert by["single"][0]["success"] is False and by["single"][0]["parse_status"] != "ok"
    # the database's nearest episode, replayed, succeeds on an in-distribution scene
    assert any(r["success"] for r in by["replay_top1"]), [r["failure_reason"] for r in by["replay_top1"]]
    for r in by["knn_blend"]:
        assert len(r["example_ids"]) == 3 and r["sim_detail"]
    grid = query("SELECT * FROM report_table3_grid", warehouse).to_pylist()
    assert [g["take"] for g in grid] == ["Take1", "Average"] and grid[0]["one_demo"] == "0/1"
    assert grid[0]["replay_top1"] == f"{sum(r['success'] for r in by['replay_top1'])}/2"
    ci = {r["strategy"]: r for r in query("SELECT * FROM report_table3_intervals", warehouse).to_pylist()}
    for s, r in ci.items():
        assert 0.0 <= r["wilson_low"] <= r["success_rate"] <= r["wilson_high"] <= 1.0
    # a second run is served from the cache: the same rows
    table3(str(warehouse), task="trash_in_bin", protocols=["thesis"], takes=1, scenes=2, llm_scenes=1,
           strategies=["replay_top1"], episodes=200, take_dirs=[str(trash_take)], show_progress=False)
    again = query("SELECT success FROM table3_trials WHERE strategy = 'replay_top1' ORDER BY scene", warehouse)
    assert again.column(0).to_pylist() == [r["success"] for r in by["replay_top1"]]


@pytest.mark.parametrize("args", [["--protocol", "bogus"], ["--strategy", "gpt"], ["--scenes", "2", "--llm-scenes", "3"]])
def test_table3_command_refuses_bad_options_in_one_line(warehouse, args):
    from typer.testing import CliRunner

    from demoforge.cli import app

    r = CliRunner().invoke(app, ["table3", *args])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1, r.output
