"""The closed-loop policy's data-scaling flow (demoforge.flows.closed_loop) end to end on an ingested take: its
table, its view, its cache; evaluating a checkpoint that does not exist says how to train one."""


def test_data_scaling_flow_writes_the_table_the_view_and_reuses_its_cache(prefect_api, ingested_warehouse, trash_take):
    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.flows.augment import augment_take_flow
    from demoforge.flows.closed_loop import data_scaling
    from demoforge.lib.trajectories.augmentation.options import AugmentOptions
    from demoforge.schemas.catalog import query

    wh = str(ingested_warehouse)
    augment_take_flow(str(trash_take), wh, augment=AugmentOptions(n=40, n_mirrored=20, seed=2), show_progress=False)
    data_scaling(wh, tasks=["trash_in_bin"], sizes=[1, 3], scenes=2, steps=20)
    ck = query("SELECT n_requested, n_episodes, frames, steps FROM closed_loop_checkpoints ORDER BY n_requested",
               wh).to_pylist()
    assert [(r["n_requested"], r["steps"]) for r in ck] == [(1, 20), (3, 20)]
    assert ck[0]["n_episodes"] <= 1 <= ck[1]["n_episodes"] <= 3 and ck[1]["frames"] > ck[0]["frames"]
    rows = query("SELECT method, n_train_episodes, scene_seed, success, failure, frames FROM closed_loop_trials",
                 wh).to_pylist()
    by = {}
    for r in rows:
        by.setdefault((r["method"], r["n_train_episodes"]), []).append(r)
    assert sorted(k[0] for k in by) == ["closed_loop", "closed_loop", "open_loop", "replay_top1", "transform_demo"]
    seeds = {k: sorted(r["scene_seed"] for r in v) for k, v in by.items()}
    assert len({tuple(s) for s in seeds.values()}) == 1 and len(next(iter(seeds.values()))) == 2  # the same scenes
    assert all(r["success"] or r["failure"] for r in rows)
    view = query("SELECT * FROM report_data_scaling", wh).to_pylist()
    assert len(view) == 5 and all(v["scenes"] == 2 and 0 <= v["wilson_low"] <= v["success_rate"] <= v["wilson_high"] <= 1
                                  for v in view)
    data_scaling(wh, tasks=["trash_in_bin"], sizes=[1, 3], scenes=2, steps=20)   # cached: nothing new
    assert query("SELECT count(*) AS n FROM closed_loop_checkpoints", wh).to_pylist()[0]["n"] == 2
    r = CliRunner().invoke(app, ["eval-policy", "--closed-loop", "--task", "trash_in_bin", "--checkpoint", "cl-nosuch"])
    assert r.exit_code == 2 and "train-policy --closed-loop" in r.output
