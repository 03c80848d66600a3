"""End-to-end: the synthesize-takes flow on short takes, through Prefect, into the warehouse."""

import json
from pathlib import Path

import numpy as np
import pytest

from demoforge.flows.synth import synthesize_takes
from demoforge.schemas.catalog import query
from demoforge.schemas.core import read_table


def test_flow_registers_take_and_ground_truth_and_serves_second_run_from_cache(prefect_api, warehouse, monkeypatch):
    (m,) = synthesize_takes(str(warehouse), tasks=["trash_in_bin"], takes=1, seed=3, mirror="yes",
                            max_frames=12, video=False, show_progress=False)
    take_dir = Path(m.path)
    assert take_dir.name == "synth_trash_in_bin_s0003_m" and take_dir.parent == warehouse / "synthetic"
    assert len(list((take_dir / "rgb").glob("*.png"))) == 12 and len(list((take_dir / "depth").glob("*.npy"))) == 12
    cam = json.loads((take_dir / "camera.json").read_text())
    assert np.array(cam["K"]).shape == (3, 3) and np.array(cam["T_world_camera"]).shape == (4, 4)

    row = query("SELECT * FROM takes").to_pylist()
    assert len(row) == 1 and row[0]["mirror"] is True and row[0]["n_frames"] == 12
    assert row[0]["provenance"] == "ground truth (synthetic)" and row[0]["source"] == "synthetic"
    assert row[0]["replay_success"] is None  # truncated takes are not replayed
    n = query("SELECT count(*) AS n FROM gt_hand_joints WHERE take = 'synth_trash_in_bin_s0003_m'")
    assert n.column("n")[0].as_py() == 24  # 12 frames x 2 hands
    kp = read_table("gt_object_keypoints", warehouse, task="trash_in_bin", take="synth_trash_in_bin_s0003_m")
    assert np.array(kp.column("keypoints_world").to_pylist()).shape == (12, 11, 3)

    def must_not_run(*a, **k):
        raise AssertionError("cached take was regenerated")

    monkeypatch.setattr("demoforge.lib.synth.take.generate_take", must_not_run)
    (m2,) = synthesize_takes(str(warehouse), tasks=["trash_in_bin"], takes=1, seed=3, mirror="yes",
                             max_frames=12, video=False, show_progress=False)
    assert m2 == m


def test_partial_take_from_a_crash_is_discarded_and_regenerated(prefect_api, warehouse, monkeypatch):
    calls = {"n": 0}
    from demoforge.lib.synth.take import generate_take as real

    def crash_after_writing_some(task, seed, mirror, out_dir, **kw):
        calls["n"] += 1
        Path(out_dir, "rgb").mkdir(parents=True)
        Path(out_dir, "rgb", "000000.png").write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr("demoforge.lib.synth.take.generate_take", crash_after_writing_some)
    with pytest.raises(BaseException):
        synthesize_takes(str(warehouse), tasks=["pouring"], takes=1, seed=1, max_frames=5, video=False,
                         show_progress=False)
    synthetic = warehouse / "synthetic"
    assert not (synthetic / "synth_pouring_s0001").exists()  # no half take under the real name
    assert query("SELECT count(*) AS n FROM takes").column("n")[0].as_py() == 0
    monkeypatch.setattr("demoforge.lib.synth.take.generate_take", real)
    (m,) = synthesize_takes(str(warehouse), tasks=["pouring"], takes=1, seed=1, max_frames=5, video=False,
                            show_progress=False)
    assert len(list(Path(m.path, "rgb").glob("*.png"))) == 5
    assert not list(synthetic.glob(".*partial"))


def test_bad_parameters_are_refused_clearly(prefect_api, warehouse):
    with pytest.raises(ValueError, match="unknown task"):
        synthesize_takes(str(warehouse), tasks=["juggling"])
    with pytest.raises(ValueError, match="mirror must be"):
        synthesize_takes(str(warehouse), tasks=["pouring"], mirror="sideways")
