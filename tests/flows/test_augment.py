"""The augment flow (demoforge.flows.augment) end to end on one full synthetic take, through Prefect: augment and
retrieve, the mapping options of the take's ingest kept, regenerated episodes drop the robot checks. (The ingest
and simulate flows on the same take: test_ingest.py, test_sim.py.)"""

import numpy as np
import pytest
from typer.testing import CliRunner

from demoforge.flows.augment import augment_take_flow, retrieve
from demoforge.cli import app
from demoforge.schemas.catalog import query
from demoforge.lib.trajectories.augmentation.options import AugmentOptions


@pytest.fixture()
def take_dir(trash_take):
    return trash_take


def test_augment_flow_and_retrieval(prefect_api, ingested_warehouse, take_dir):
    warehouse = ingested_warehouse  # the take ingested once per session
    out = augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=400, n_mirrored=200, seed=3), show_progress=False)
    ep = query("SELECT kind, count(*) AS n, sum(length) AS steps, count(*) FILTER (WHERE valid) AS valid "
               "FROM episodes GROUP BY kind ORDER BY kind", warehouse).to_pylist()
    assert {r["kind"]: r["n"] for r in ep} == {"mirrored": 200, "original": 1, "translated": 200}
    total_steps = sum(r["steps"] for r in ep)
    n_steps = query("SELECT count(*) AS n FROM episode_steps", warehouse).column("n")[0].as_py()
    assert n_steps == total_steps
    assert sum(r["valid"] for r in ep) > 0.6 * 401
    seg = query("SELECT arm, kind FROM segments ORDER BY arm, start", warehouse).to_pylist()
    for arm in (0, 1):
        kinds = [r["kind"] for r in seg if r["arm"] == arm]
        assert "skill" in kinds and all(a != b for a, b in zip(kinds, kinds[1:]))  # alternating
    sm = query("SELECT * FROM segmentation_metrics", warehouse).to_pylist()
    assert all(r["matched"] == r["boundaries_true"] and r["max_error_frames"] <= 30 for r in sm)

    # the original episode's first step is the ingested demonstration's first gripper pose
    first = query("SELECT action FROM episode_steps WHERE episode_id = 0 AND step = 0", warehouse)
    pose0 = query("SELECT pose FROM gripper_poses WHERE frame = 0 ORDER BY hand", warehouse)
    np.testing.assert_allclose(np.array(first.column("action")[0].as_py()),
                               np.array(pose0.column("pose").to_pylist()), atol=1e-5)

    # querying with an episode's own keypoints retrieves that episode first, with MSE 0
    row = query("SELECT episode_id, object_keypoints FROM episodes WHERE valid AND kind = 'mirrored' "
                "ORDER BY episode_id LIMIT 1", warehouse).to_pylist()[0]
    hits = retrieve(str(warehouse), "trash_in_bin", np.array(row["object_keypoints"]), k=3)
    assert hits[0]["episode_id"] == row["episode_id"] and hits[0]["mse"] == pytest.approx(0.0, abs=1e-12)
    assert [h["mse"] for h in hits] == sorted(h["mse"] for h in hits)
    single = retrieve(str(warehouse), "trash_in_bin", np.array(row["object_keypoints"]), strategy="single")
    assert [h["episode_id"] for h in single] == [0]
    rnd = retrieve(str(warehouse), "trash_in_bin", np.array(row["object_keypoints"]), strategy="random", seed=1)
    assert len({h["episode_id"] for h in rnd}) == 3


def test_augment_keeps_the_mapping_options_the_take_was_ingested_with(prefect_api, ingested_warehouse, take_dir):
    """`demoforge augment` re-runs the (cached) ingest it builds on; it used to do so with the default
    mapping, silently replacing a take ingested with other options (e.g. --smoothing) before generating."""
    warehouse = ingested_warehouse  # the take ingested once per session
    def poses():
        t = query("SELECT pose FROM gripper_poses ORDER BY frame, hand", warehouse).column("pose").to_pylist()
        return np.asarray(t, float)

    runner = CliRunner()
    r = runner.invoke(app, ["ingest", str(take_dir), "--smoothing", "5", "--grasp-prior", "pose"])
    assert r.exit_code == 0, r.output
    ingested = poses()
    r = runner.invoke(app, ["augment", str(take_dir), "-n", "20", "--mirrored", "10", "--smoothing", "5",
                            "--grasp-prior", "pose"])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(poses(), ingested)
    # the options matter: augmenting with the defaults gives other gripper poses (and says so in --help)
    r = runner.invoke(app, ["augment", str(take_dir), "-n", "20", "--mirrored", "10"])
    assert r.exit_code == 0, r.output
    assert np.nanmax(np.abs(poses() - ingested)) > 1e-3
    assert "--smoothing" in runner.invoke(app, ["augment", "--help"]).output


def test_regenerated_episodes_drop_the_take_s_robot_checks(prefect_api, ingested_warehouse, take_dir):
    warehouse = ingested_warehouse  # the take ingested once per session
    from demoforge.flows.sim import check_stability, simulate_episodes

    def checked():
        return query("SELECT count(*) AS n FROM sim_results", warehouse).column("n")[0].as_py()

    def repeats():
        return query("SELECT count(*) AS n FROM sim_stability", warehouse).column("n")[0].as_py()

    out = augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=30, n_mirrored=10, seed=2), show_progress=False)
    simulate_episodes(str(warehouse), task="trash_in_bin", episodes=2, chunk_size=2, show_progress=False)
    check_stability(str(warehouse), task="trash_in_bin", episodes=1, repeats=2, show_progress=False)
    assert checked() == 2 and repeats() == 2
    # the same database again (cached, or rewritten with the same bytes): the checks still describe it
    augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=30, n_mirrored=10, seed=2), show_progress=False)
    assert checked() == 2
    from demoforge.tasks.augment import augment_take

    augment_take.fn(take_dir.resolve(), None, str(warehouse), out["gripper_poses"], out["object_keypoints"],
                    out["segments"], n=30, n_mirrored=10, seed=2)  # executed, not served from the cache
    assert checked() == 2
    # another database under the same take: the old checks would describe episodes that are gone
    augment_take_flow(str(take_dir), str(warehouse), augment=AugmentOptions(n=30, n_mirrored=10, seed=7), show_progress=False)
    assert checked() == 0 and repeats() == 0
    assert not list((warehouse / "_trash").rglob("*.parquet"))
