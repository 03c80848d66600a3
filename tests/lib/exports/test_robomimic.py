"""The robomimic hdf5 export (demoforge.lib.exports.robomimic) of a real episode database: layout and provenance."""

from __future__ import annotations

import json

import numpy as np

from tests.support.episodes import TAKE, TASK


def test_robomimic_export_layout_and_provenance(episode_wh, tmp_path):
    import h5py

    from demoforge.tasks.export import export_robomimic
    from demoforge.lib.exports.robomimic import is_demoforge_robomimic, read_robomimic_demo

    wh, info = episode_wh
    out = tmp_path / "pouring.hdf5"
    s = export_robomimic(str(wh), TASK, str(out), include_invalid=True, valid_fraction=0.25, seed=3)
    ids = sorted(info["actions"])
    assert s["demos"] == len(ids) and s["valid"] == round(0.25 * len(ids))
    assert is_demoforge_robomimic(out)
    with h5py.File(out, "r") as f:
        data = f["data"]
        assert data.attrs["total"] == sum(len(a) for a in info["actions"].values())
        env = json.loads(data.attrs["env_args"])
        assert env["env_name"] == "demoforge/pouring" and env["env_kwargs"]["control_freq"] == 30
        assert sorted(data.keys(), key=lambda k: int(k.split("_")[1])) == [f"demo_{i}" for i in range(len(ids))]
        train = {x.decode() for x in f["mask/train"][()]}
        valid = {x.decode() for x in f["mask/valid"][()]}
        assert not train & valid and train | valid == set(data.keys())
        mirrored = {x.decode() for x in f["mask/mirrored"][()]}
        assert len(mirrored) == sum(k == "mirrored" for k in info["kind"].values())
    for i in (0, len(ids) - 1):
        d = read_robomimic_demo(out, f"demo_{i}")
        src = info["actions"][d["attrs"]["src_episode_id"]].astype(np.float64)
        assert d["attrs"]["src_take"] == TAKE and d["attrs"]["src_task"] == TASK
        assert d["attrs"]["src_kind"] == info["kind"][d["attrs"]["src_episode_id"]]
        assert d["attrs"]["num_samples"] == len(src) == len(d["actions"])
        np.testing.assert_allclose(d["obs"]["robot0_eef_pos"], src[:, 0, :3], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["robot1_eef_quat"], src[:, 1, 3:7], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["robot0_gripper"][:, 0], src[:, 0, 7])
        np.testing.assert_allclose(d["actions"][:-1], src[1:].reshape(-1, 16), atol=1e-6)
        np.testing.assert_allclose(d["next_obs"]["robot1_eef_pos"][:-1], src[1:, 1, :3], atol=1e-6)
        np.testing.assert_allclose(d["obs"]["object"][0], info["keypoints"][d["attrs"]["src_episode_id"]].reshape(-1),
                                   atol=1e-6)
        # the keypoints follow the carried objects: the bottle (manipulated) is lifted off its start
        # (and put back), the next observation is the next step's
        assert np.abs(d["obs"]["object"] - d["obs"]["object"][0]).max() > 0.05
        np.testing.assert_allclose(d["next_obs"]["object"][:-1], d["obs"]["object"][1:])
        assert d["dones"].sum() == 1 and d["dones"][-1] == 1
