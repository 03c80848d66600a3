"""The policy flows on a tiny warehouse: train (cached, reproducible) -> evaluate in MuJoCo -> tables
(`policy_checkpoints`, `policy_trials`, `llm_trials` strategy `policy` -> report_table3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from demoforge.schemas.catalog import query
from tests.support.episodes import SCRIPTED_TAKE as TAKE, scripted_database


def test_policy_flows_train_evaluate_and_report(prefect_api, warehouse):
    import json

    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.flows.policy import train_policy
    from demoforge.tasks.policy import load_policy_data

    scripted_database(warehouse)
    wh = str(warehouse)
    data, ep = load_policy_data(wh, "pouring", TAKE, 20)
    assert len(data) == int(np.sum(ep.column("valid").to_numpy(zero_copy_only=False)))
    assert data.waypoints.shape == (len(data), 20, 2, 8)

    # the commands' main paths: train-policy's options reach the flow (and the checkpoint's record)
    r = CliRunner().invoke(app, ["train-policy", "--task", "pouring", "--seed", "3", "--epochs", "2", "--d-model", "16",
                                 "--layers", "1", "--batch-size", "16"])
    assert r.exit_code == 0, r.output
    row = query("SELECT * FROM policy_checkpoints", warehouse).to_pylist()
    assert len(row) == 1 and row[0]["epochs_run"] == 2 and row[0]["threads"] == 1 and row[0]["seed"] == 3
    ck = row[0]
    config = json.loads(ck["config"])
    assert (config["policy"]["d_model"], config["policy"]["enc_layers"], config["train"]["batch_size"]) == (16, 1, 16)
    assert ck["checkpoint_id"] in r.stdout                   # the record it prints
    kw = dict(task="pouring", seed=3, epochs=2, d_model=16, layers=1, batch_size=16)
    stamp = (Path(ck["path"]) / "model.pt").stat().st_mtime_ns
    m = train_policy(wh, **kw)                               # the same options as a flow call: the command's cache entry
    assert (Path(ck["path"]) / "model.pt").stat().st_mtime_ns == stamp
    assert ck["n_train"] + ck["n_val"] == len(data) and ck["n_val"] > 0
    assert len(ck["val_loss_history"]) == 2 and np.isfinite(ck["val_loss"]) and ck["val_pos_err_mm"] > 0
    pt = Path(ck["path"]) / "model.pt"
    assert pt.is_file() and (Path(ck["path"]) / "config.json").is_file()
    assert Path(ck["path"]).parent.parent.parent == warehouse / "_policy"

    # same inputs: a cache hit; the weights file deleted: trained again, to the same weights (seeded)
    assert train_policy(wh, **kw) == m
    pt.unlink()
    m2 = train_policy(wh, **kw)
    assert pt.is_file() and m2.path == m.path  # the path names the checkpoint id: the same weights again
    assert query("SELECT checkpoint_id FROM policy_checkpoints", warehouse).column(0).to_pylist() == [ck["checkpoint_id"]]

    r = CliRunner().invoke(app, ["eval-policy", "--task", "pouring", "--trials", "1", "--seed", "0"])
    assert r.exit_code == 0, r.output
    trials = query("SELECT * FROM policy_trials ORDER BY scene_kind", warehouse).to_pylist()
    assert all(kind in r.stdout for kind in ("held_out", "in_distribution", "mirrored", "out_of_distribution"))
    assert [t["scene_kind"] for t in trials] == ["held_out", "in_distribution", "mirrored", "out_of_distribution"]
    for t in trials:
        assert t["checkpoint_id"] == ck["checkpoint_id"] and t["latency_ms"] > 0
        assert np.asarray(t["predicted_waypoints"]).shape == (20, 2, 8)
    held, ind, _, ood = trials
    # each verdict is the simulator's verdict on the predicted waypoints, spread over the original's length
    from demoforge.lib.sim import FAILURES, execute
    from demoforge.tasks.llm_eval import upsample

    n_steps = query("SELECT length FROM episodes WHERE kind = 'original'", warehouse).column(0)[0].as_py()
    for t in (ind, ood):
        r = execute("pouring", np.asarray(t["query_keypoints"]), upsample(np.asarray(t["predicted_waypoints"]), n_steps))
        assert (t["success"], t["failure_reason"], t["sim_detail"]) == (r.success, r.failure or "", r.detail)
    assert all(t["success"] or t["failure_reason"] in FAILURES for t in trials)
    assert ood["in_augmented_region"] is False and ood["max_offset_m"] > 0
    assert held["in_augmented_region"] is True  # a database placement the policy did not train on
    trained = json.loads((Path(ck["path"]) / "config.json").read_text())["train_episode_ids"]
    db = query("SELECT episode_id, object_keypoints FROM episodes WHERE valid AND episode_id <> 0", warehouse).to_pylist()
    match = [r["episode_id"] for r in db if np.allclose(r["object_keypoints"], held["query_keypoints"])]
    assert match and match[0] not in trained
    # the in-distribution scene is the prompting evaluation's query scene
    from demoforge.tasks.llm_eval import query_scene

    np.testing.assert_allclose(ind["query_keypoints"], query_scene("pouring", 0, 0)[1])
    llm = query("SELECT * FROM llm_trials", warehouse).to_pylist()
    assert len(llm) == 1 and llm[0]["strategy"] == "policy" and llm[0]["backend"] == "torch"
    assert llm[0]["model"] == ck["checkpoint_id"] and llm[0]["success"] == ind["success"]
    assert llm[0]["latency_s"] == pytest.approx(ind["latency_ms"] / 1000)
    t3 = query("SELECT strategy, backend, trials FROM report_table3", warehouse).to_pylist()
    assert t3 == [{"strategy": "policy", "backend": "torch", "trials": 1}]


def test_policy_flows_explain_missing_inputs(prefect_api, warehouse):
    from demoforge.flows.policy import evaluate_policy, train_policy

    with pytest.raises(ValueError, match="augment"):
        train_policy(str(warehouse), task="pouring", epochs=1)
    with pytest.raises(ValueError, match="unknown task"):
        train_policy(str(warehouse), task="juggling", epochs=1)
    scripted_database(warehouse, n=8)
    with pytest.raises(ValueError, match="train-policy"):
        evaluate_policy(str(warehouse), task="pouring", trials=1)
    with pytest.raises(ValueError, match="no episode database of take"):
        train_policy(str(warehouse), task="pouring", take="other", epochs=1)


def test_policy_commands_reject_bad_options_with_one_line_errors(warehouse):
    from typer.testing import CliRunner

    from demoforge.cli import app

    runner = CliRunner()
    r = runner.invoke(app, ["--warehouse", str(warehouse), "eval-policy", "--kind", "sideways"])
    assert r.exit_code == 2 and "unknown --kind 'sideways'" in r.output
    r = runner.invoke(app, ["--warehouse", str(warehouse), "train-policy", "--d-model", "30"])
    assert r.exit_code == 2 and "multiple of 4" in r.output
    for cmd in ("train-policy", "eval-policy"):
        r = runner.invoke(app, [cmd, "--help"])
        assert r.exit_code == 0 and ("MuJoCo" in r.output or "Transformer" in r.output)
