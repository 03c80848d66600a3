"""LeRobot's per-feature statistics (demoforge.lib.exports.lerobot_stats) equal LeRobot's own histogram algorithm."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from tests.support.lerobot_reference import reference_episode_quantiles


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 4), st.integers(1, 300), st.integers(1, 5))
def test_lerobot_stats_equal_lerobots_histogram_algorithm(seed, n_eps, length, dims):
    """The vectorised statistics equal a per-dimension transcription of LeRobot's RunningQuantileStats
    (to one histogram bin), and the aggregate is LeRobot's count-weighted one."""
    from demoforge.lib.exports.lerobot_stats import aggregate_stats, lerobot_stats

    rng = np.random.default_rng(seed)
    x = rng.normal(0, rng.uniform(0.01, 5), (n_eps, length, dims)).astype(np.float32)
    x[:, :, 0] = np.round(x[:, :, 0])  # ties and repeated values
    s = lerobot_stats(x)
    for e in range(n_eps):
        np.testing.assert_allclose(s["mean"][e], x[e].mean(0), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(s["std"][e], x[e].std(0), rtol=1e-3, atol=1e-4)
        if length < 2:
            continue
        ref = reference_episode_quantiles(x[e].astype(np.float64))
        width = (x[e].max(0) - x[e].min(0)) / 5000 + 1e-9
        for k, v in ref.items():
            assert (np.abs(s[k][e] - v) <= width * 1.01).all(), (k, s[k][e], v)
    agg = aggregate_stats(s)
    flat = x.reshape(-1, dims).astype(np.float64)
    np.testing.assert_allclose(agg["mean"], flat.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(agg["std"], flat.std(0), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(agg["q50"], s["q50"].astype(np.float64).mean(0), rtol=1e-6)  # equal counts: the plain mean
    assert agg["count"].tolist() == [n_eps * length]
