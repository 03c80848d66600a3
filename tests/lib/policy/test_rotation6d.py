"""6D rotations (demoforge.lib.policy.rotation6d): round trips, proper rotations in numpy and torch, the
geodesic."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from demoforge.lib.geometry import quat_angle
from demoforge.lib.policy.rotation6d import (
    matrix_from_6d, quat_from_6d, quat_to_6d, torch_geodesic, torch_matrix_from_6d,
)


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
