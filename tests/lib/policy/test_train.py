"""The learned policy's pure parts: 6D rotations, batch resampling, the placement split, training
(overfits a small set, reproducible from a seed), checkpoints, out-of-distribution scenes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from demoforge.lib.geometry import quat_angle
from demoforge.lib.policy.data import (
    PolicyData, Normalizer, resample_batch, split_by_placement, waypoint_times,
)
from demoforge.lib.policy.model import KeypointPolicy, PolicyConfig
from demoforge.lib.policy.rotation6d import (
    matrix_from_6d, quat_from_6d, quat_to_6d, torch_geodesic, torch_matrix_from_6d,
)
from demoforge.lib.policy.train import (
    TrainConfig, checkpoint_id, evaluate, load_checkpoint, save_checkpoint, train_policy, weights_digest,
)
from demoforge.lib.llm.prompting import resample_actions

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
quats = st.lists(finite, min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1).map(
    lambda v: np.asarray(v) / np.linalg.norm(v))


@given(quats)
@settings(max_examples=100, deadline=None)
def test_6d_round_trip_keeps_the_rotation(q):
    d6 = quat_to_6d(q)
    assert d6.shape == (6,)
    assert float(quat_angle(q, quat_from_6d(d6))) < 1e-7
    np.testing.assert_allclose(quat_to_6d(quat_from_6d(d6)), d6, atol=1e-9)  # 6D of a rotation is a fixed point


# non-degenerate: neither column tiny (the function clamps norms at 1e-8), not parallel
@given(st.lists(finite, min_size=6, max_size=6).filter(
    lambda v: np.linalg.norm(np.cross(v[:3], v[3:])) > 1e-2 * np.linalg.norm(v[:3]) * np.linalg.norm(v[3:])
    and np.linalg.norm(v[:3]) > 1e-2 and np.linalg.norm(v[3:]) > 1e-4))
@settings(max_examples=100, deadline=None)
def test_any_6d_vector_maps_to_a_proper_rotation_in_numpy_and_torch(v):
    R = matrix_from_6d(np.asarray(v))
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(R[:, 0], np.asarray(v[:3]) / np.linalg.norm(v[:3]), atol=1e-9)  # first column kept
    Rt = torch_matrix_from_6d(torch.tensor(v, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(Rt, R, atol=1e-9)


@given(quats, quats)
@settings(max_examples=100, deadline=None)
def test_torch_geodesic_is_the_rotation_angle(a, b):
    ang = torch_geodesic(torch.tensor(quat_to_6d(a)), torch.tensor(quat_to_6d(b))).item()
    assert ang == pytest.approx(float(quat_angle(a, b)), abs=3e-3)  # acos is clamped 1e-6 from +-1


def _random_actions(rng, n):
    a = np.zeros((n, 2, 8))
    a[..., :3] = np.cumsum(rng.normal(0, 0.01, (n, 2, 3)), axis=0)
    q = rng.normal(size=4) + np.cumsum(rng.normal(0, 0.05, (n, 2, 4)), axis=0)
    a[..., 3:7] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    switch = rng.integers(1, n, size=(2, 2)) if n > 1 else np.zeros((2, 2), int)
    for arm in range(2):  # open, closed between two switch steps, open again
        lo, hi = np.sort(switch[arm])
        a[:, arm, 7] = 1.0
        a[lo:hi, arm, 7] = 0.0
    return a


def test_resample_batch_equals_the_prompts_resampling_per_episode():
    rng = np.random.default_rng(3)
    lengths = np.array([50, 50, 37, 1, 2, 19, 50, 12])
    acts = np.zeros((len(lengths), 50, 2, 8))
    for i, n in enumerate(lengths):
        acts[i, :n] = _random_actions(rng, n)
        acts[i, n:] = acts[i, n - 1]  # padding
    acts[1] = acts[0]  # a shared group
    for m in (2, 5, 20):
        got = resample_batch(acts, lengths, m)
        ref = np.stack([resample_actions(acts[i, :n], m) for i, n in enumerate(lengths)])
        np.testing.assert_allclose(got, ref, atol=1e-12)
    assert waypoint_times(np.ones((40, 2), bool), 5).tolist() == [0, 9.75, 19.5, 29.25, 39]
    with pytest.raises(ValueError, match="lengths"):
        resample_batch(acts, lengths + 1, 20)


def _scripted_data(n: int = 40, n_mirrored: int = 20, seed: int = 1, n_wp: int = 8) -> PolicyData:
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
    from demoforge.lib.task_library import get_task

    spec = get_task("pouring")
    batch = generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=n, n_mirrored=n_mirrored,
                              seed=seed, materialize=True)
    return PolicyData(batch.episode_id, batch.kind, batch.params, batch.keypoints, batch.initial,
                      resample_batch(batch.actions, batch.lengths, n_wp))


@pytest.fixture(scope="module")
def scripted():
    return _scripted_data()


def test_split_keeps_placements_whole_and_is_seeded(scripted):
    d = scripted.subset(np.r_[np.arange(len(scripted)), 5, 6, 30])  # repeated placements must stay together
    tr, va = split_by_placement(d, 0.25, seed=0)
    assert len(np.intersect1d(tr, va)) == 0 and len(tr) + len(va) == len(d)
    assert 0 in d.episode_id[tr]  # the original demonstration trains
    key = lambda i: (d.kind[i], tuple(np.round(d.placement[i].ravel(), 6)))  # noqa: E731
    assert not {key(i) for i in tr} & {key(i) for i in va}
    tr2, va2 = split_by_placement(d, 0.25, seed=0)
    assert np.array_equal(va, va2)
    assert not np.array_equal(va, split_by_placement(d, 0.25, seed=1)[1])
    with pytest.raises(ValueError, match="val_fraction"):
        split_by_placement(d, 1.0, 0)


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


def test_out_of_distribution_placements_leave_the_translation_box_and_stay_on_the_table(scripted):
    from demoforge.lib.policy.scenes import in_box, ood_placement, placement_offsets, translation_box
    from demoforge.lib.sim.executor import object_poses_from_keypoints
    from demoforge.lib.task_library import get_task

    spec = get_task("pouring")
    box = translation_box(scripted.placement[1:])
    assert np.all(box[0] < 0) and np.all(box[1] > 0)
    original = object_poses_from_keypoints(spec, scripted.keypoints[0])
    # the database's own translated episodes are inside the box
    for i in np.flatnonzero(scripted.kind == "translated")[:5]:
        assert in_box(placement_offsets(original, object_poses_from_keypoints(spec, scripted.keypoints[i])), box, 1e-6)
    for s in range(10):
        poses = ood_placement(original, box, np.random.default_rng(s), spec.keypoints_world, spec.workspace)
        assert not in_box(placement_offsets(original, poses), box)
        kp = spec.keypoints_world(poses)
        assert np.all(kp[:, :2] >= spec.workspace[0, :2]) and np.all(kp[:, :2] <= spec.workspace[1, :2])
        np.testing.assert_allclose(poses[:, :3, :3], original[:, :3, :3])  # translation only
    with pytest.raises(ValueError, match="workspace"):
        ood_placement(original, box, np.random.default_rng(0), spec.keypoints_world,
                      np.array([[-0.01, -0.01, 0], [0.01, 0.01, 1]]), tries=50)
