"""What the exports share (demoforge.lib.exports): next_poses keeps each episode's last pose."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from demoforge.lib.exports import next_poses


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 6), min_size=1, max_size=6))
def test_next_poses_shifts_within_episodes_only(lengths):
    lengths = np.array(lengths)
    F = int(lengths.sum())
    poses = np.arange(F * 16, dtype=float).reshape(F, 2, 8)
    nxt = next_poses(poses, lengths)
    ends = np.cumsum(lengths) - 1
    inner = np.setdiff1d(np.arange(F), ends)
    np.testing.assert_array_equal(nxt[inner], poses[inner + 1])
    np.testing.assert_array_equal(nxt[ends], poses[ends])
