"""Training the learned policy (demoforge.lib.policy.train): it overfits a small set, is reproducible from a seed,
its checkpoints round-trip, the model refuses wrong shapes. (Its other parts: test_rotation6d.py, test_data.py,
test_scenes.py beside this file.)"""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.geometry import quat_angle
from demoforge.lib.policy.data import Normalizer, split_by_placement
from demoforge.lib.policy.model import KeypointPolicy, PolicyConfig
from demoforge.lib.policy.train import (
    TrainConfig, checkpoint_id, evaluate, load_checkpoint, save_checkpoint, train_policy, weights_digest,
)
from tests.support.episodes import scripted_policy_data


@pytest.fixture(scope="module")
def scripted():
    return scripted_policy_data()


def test_policy_overfits_a_small_database(scripted):
    """Loss falls by orders of magnitude and predictions reproduce the training trajectories."""
    d = scripted.subset(np.arange(12))
    cfg = PolicyConfig(n_waypoints=8, d_model=32, ff_dim=64, enc_layers=1, dec_layers=1)
    res = train_policy(d, d.subset([0, 1]), seed=0, config=cfg,
                       train_config=TrainConfig(epochs=120, batch_size=12, lr=5e-3, warmup_steps=10))
    h = res.history
    assert h[-1].train_loss < h[0].train_loss / 30
    pred = res.model.predict(d.keypoints, d.initial)
    assert pred.shape == (12, 8, 2, 8)
    pos_err = np.linalg.norm(pred[..., :3] - d.waypoints[..., :3], axis=-1)
    assert np.median(pos_err) < 0.005 and pos_err.max() < 0.02  # metres
    assert np.median(quat_angle(pred[..., 3:7], d.waypoints[..., 3:7])) < np.radians(5)
    np.testing.assert_allclose(np.linalg.norm(pred[..., 3:7], axis=-1), 1.0, atol=1e-9)
    assert (pred[..., 7] == d.waypoints[..., 7]).mean() > 0.95
    assert res.val_metrics["pos_err_mm"] < 10
    one = res.model.predict(d.keypoints[3], d.initial[3])  # the single-scene form
    np.testing.assert_allclose(one, pred[3], atol=1e-5)


def test_training_is_reproducible_from_the_seed_and_checkpoints_round_trip(scripted, tmp_path):
    tr, va = split_by_placement(scripted, 0.2, seed=0)
    cfg = PolicyConfig(n_waypoints=8, d_model=16, ff_dim=32, enc_layers=1, dec_layers=1, dropout=0.1)
    tc = TrainConfig(epochs=3, batch_size=8)
    a = train_policy(scripted.subset(tr), scripted.subset(va), seed=7, config=cfg, train_config=tc)
    b = train_policy(scripted.subset(tr), scripted.subset(va), seed=7, config=cfg, train_config=tc)
    c = train_policy(scripted.subset(tr), scripted.subset(va), seed=8, config=cfg, train_config=tc)
    assert weights_digest(a.model) == weights_digest(b.model) != weights_digest(c.model)
    assert [h.train_loss for h in a.history] == [h.train_loss for h in b.history]
    pt, js = save_checkpoint(a.model, tmp_path / "ck", {"seed": 7})
    back = load_checkpoint(tmp_path / "ck")
    assert checkpoint_id(back) == checkpoint_id(a.model) and checkpoint_id(back).startswith("kp-")
    np.testing.assert_array_equal(back.predict(scripted.keypoints[:4], scripted.initial[:4]),
                                  a.model.predict(scripted.keypoints[:4], scripted.initial[:4]))
    assert evaluate(back, scripted.subset(va), tc)["loss"] == pytest.approx(a.val_metrics["loss"], rel=1e-6)
    assert '"seed": 7' in js.read_text()
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(Exception):
        load_checkpoint(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError, match="train-policy"):
        load_checkpoint(tmp_path / "nothing")


def test_model_rejects_wrong_shapes_and_config_mismatch(scripted):
    m = KeypointPolicy(PolicyConfig(n_waypoints=8), Normalizer.fit(scripted))
    with pytest.raises(ValueError, match="keypoints"):
        m.predict(np.zeros((10, 3)), np.zeros((2, 8)))
    with pytest.raises(ValueError, match="multiple"):
        PolicyConfig(d_model=30, n_heads=4)
    with pytest.raises(ValueError, match="waypoints"):
        train_policy(scripted, scripted, config=PolicyConfig(n_waypoints=20), train_config=TrainConfig(epochs=1))
