"""Table 3 machinery end to end: episode database -> prompts -> backend -> parser -> MuJoCo check."""

from demoforge.flows.augment import augment_take_flow
from demoforge.schemas.catalog import query
from demoforge.lib.trajectories.augmentation.options import AugmentOptions


def test_llm_eval_flow_parses_judges_and_records(prefect_api, ingested_warehouse, trash_take, monkeypatch):
    """Table 3 machinery with a scripted backend (the real local model is tested in test_llm_backends):
    a well-formed answer is parsed and judged in MuJoCo, garbage becomes a failed trial, not a crash.
    Trial 0's query scene is the take's own scene, so the demonstration itself is a known-good answer
    there (and the LLM-free baselines replay it); trial 1 is a new scene."""
    warehouse = ingested_warehouse  # the take ingested once per session
    import demoforge.tasks.llm_eval as te
    from demoforge.flows.llm_eval import llm_eval
    from demoforge.lib.llm.prompting import format_actions, resample_actions
    from demoforge.lib.sim import FAILURES
    from demoforge.lib.task_library import get_task
    from demoforge.schemas.reads.episodes import episode_actions

    spec = get_task("trash_in_bin")
    take_poses = spec.scripted_demo(0).placement.object_poses  # the synthetic take's scene (seed 0)
    new_scene = te.query_scene
    monkeypatch.setattr(te, "query_scene", lambda task, seed, trial: (
        (take_poses, spec.keypoints_world(take_poses)) if trial == 0 else new_scene(task, seed, trial)))
    augment_take_flow(str(trash_take), str(warehouse), augment=AugmentOptions(n=60, n_mirrored=30, seed=1), show_progress=False)
    demo = episode_actions(str(warehouse), "trash_in_bin", trash_take.name, [0])[0]
    good = "Sure, here it is:\n" + format_actions(resample_actions(demo, 20)) + "\nDone."
    llm_eval(str(warehouse), task="trash_in_bin", strategies=["single"], backend="fake",
             backend_options={"responses": [good]}, trials=2, seed=5)
    llm_eval(str(warehouse), task="trash_in_bin", strategies=["retrieval"], backend="fake",
             backend_options={"responses": ["I cannot help with that [[[0.1, 0.2"]}, trials=2, seed=5)
    llm_eval(str(warehouse), task="trash_in_bin", strategies=["replay_top1", "transform_demo"], trials=2, seed=5)
    rows = query("SELECT * FROM llm_trials ORDER BY strategy, trial", warehouse).to_pylist()
    by = {}
    for r in rows:
        by.setdefault(r["strategy"], []).append(r)
    assert set(by) == {"single", "retrieval", "replay_top1", "transform_demo"}
    for r in by["single"]:
        assert r["parse_status"] == "ok" and r["prompt_tokens"] > 100 and r["raw_answer"] == good
        assert r["retrieved_episode_ids"] == [0] and r["sim_detail"]  # judged by the simulator
    for strategy in ("single", "replay_top1", "transform_demo"):
        known_good, new = by[strategy]
        assert known_good["success"] is True and known_good["failure_reason"] == "", (strategy, known_good["sim_detail"])
        assert new["success"] or new["failure_reason"] in FAILURES, (strategy, new["failure_reason"])
    assert by["replay_top1"][0]["retrieved_episode_ids"] == [0]  # the take's own scene: its original first
    for r in by["retrieval"]:
        assert r["success"] is False and r["parse_status"] in ("no_array", "truncated", "wrong_shape")
        assert r["failure_reason"] == r["parse_status"] and r["sim_detail"] == ""  # never simulated
        assert len(r["retrieved_episode_ids"]) == 3 and r["raw_answer"].startswith("I cannot")
    for r in by["replay_top1"] + by["transform_demo"]:
        assert r["backend"] == "none" and r["parse_status"] == "ok" and r["sim_detail"]
    t3 = query("SELECT strategy, trials FROM report_table3", warehouse).to_pylist()
    assert {r["strategy"]: r["trials"] for r in t3} == {s: 2 for s in by}

