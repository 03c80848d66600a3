"""Retrieval: exact top-k equals brute force (random data, ties), metrics, selections."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from demoforge.lib.trajectories import retrieval as rt
from demoforge.lib.trajectories.augmentation import mirror_permutation
from demoforge.lib.task_library import get_task


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 300), k=st.integers(1, 12), seed=st.integers(0, 10_000), ties=st.booleans(),
       scale=st.sampled_from([1e-3, 1.0, 100.0]))
def test_topk_equals_brute_force(n, k, seed, ties, scale):
    rng = np.random.default_rng(seed)
    kp = rng.normal(size=(n, 11, 3)) * scale
    if ties:  # duplicated scenes and a coarse grid -> many exact ties
        kp = np.round(kp[rng.integers(0, max(1, n // 3), n)] * 2) / 2
    ids = rng.permutation(10 * n)[:n]
    q = kp[rng.integers(0, n)] + (0 if ties else rng.normal(size=(11, 3)) * 0.1 * scale)
    idx = rt.KeypointIndex(kp, ids)
    res = idx.query(q, k)
    bid, bmse = rt.mse_brute_force(kp, ids, q, k)
    np.testing.assert_array_equal(res.ids[0], bid)
    np.testing.assert_allclose(res.mse[0], bmse, rtol=1e-12, atol=0)


def test_batched_queries_and_exclude():
    rng = np.random.default_rng(0)
    kp = rng.uniform(-0.3, 0.3, size=(2000, 11, 3))
    idx = rt.KeypointIndex(kp)
    Q = kp[:5] + 1e-4
    res = idx.query(Q, 3)
    assert res.ids.shape == (5, 3)
    np.testing.assert_array_equal(res.ids[:, 0], np.arange(5))
    for i in range(5):
        np.testing.assert_array_equal(res.ids[i], idx.query(Q[i], 3).ids[0])
    ex = idx.query(kp[7], 3, exclude_ids=[7])
    assert 7 not in ex.ids[0]
    np.testing.assert_array_equal(ex.ids[0], rt.mse_brute_force(np.delete(kp, 7, 0), np.delete(np.arange(2000), 7), kp[7], 3)[0])


def test_mirror_metrics():
    t = get_task("pouring")
    perm = mirror_permutation(t.keypoints_local, t.keypoint_object)
    plain = t.keypoints_world(t.scripted_demo(0).placement.object_poses)
    mirrored = t.keypoints_world(t.scripted_demo(0, True).placement.object_poses)
    rng = np.random.default_rng(1)
    db = np.concatenate([plain[None], rng.uniform(-0.3, 0.3, (50, 11, 3))])
    idx = rt.KeypointIndex(db, mirror_perm=perm)
    r = idx.query(mirrored, 1, metric="mse_mirrored")
    assert r.ids[0, 0] == 0 and r.mse[0, 0] < 1e-24 and r.mirrored[0, 0]
    r = idx.query(mirrored, 1, metric="min")
    assert r.ids[0, 0] == 0 and r.mirrored[0, 0]
    r = idx.query(plain, 1, metric="min")
    assert r.ids[0, 0] == 0 and not r.mirrored[0, 0]


def test_selections():
    ids = np.arange(100, 200)
    kinds = np.array(["original"] + ["translated"] * 99)
    s = rt.select_random(ids, 3, seed=5)
    assert len(set(s)) == 3 and set(s) <= set(ids)
    np.testing.assert_array_equal(s, rt.select_random(ids, 3, seed=5))
    assert list(rt.select_original(ids, kinds)) == [100]
    assert list(rt.select("single", ids=ids, kinds=kinds)) == [100]
    idx = rt.KeypointIndex(np.random.default_rng(0).normal(size=(100, 11, 3)), ids)
    assert len(rt.select("retrieval", idx, query=np.zeros((11, 3)))) == 3
