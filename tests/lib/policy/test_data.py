"""The policy's data (demoforge.lib.policy.data): batch resampling equals the prompt's, the split keeps placements
whole and is seeded."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.llm.prompting import resample_actions
from demoforge.lib.policy.data import resample_batch, split_by_placement, waypoint_times
from tests.support.episodes import scripted_policy_data


@pytest.fixture(scope="module")
def scripted():
    return scripted_policy_data()


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
