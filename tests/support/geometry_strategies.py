"""Hypothesis strategies and checks for the geometry tests (tests/lib/geometry/): unit quaternions, vectors,
points, rotations, and the example budgets."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, assume, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from demoforge.lib import geometry as G

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

coord = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
unit_coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def quats(draw, shape=()):
    """Unit quaternions (scalar-last) of the given batch shape, from normalised 4-vectors."""
    raw = draw(hnp.arrays(np.float64, tuple(shape) + (4,), elements=unit_coord))
    norm = np.linalg.norm(raw, axis=-1)
    assume(np.all(norm > 1e-3))
    return raw / norm[..., None]


@st.composite
def vectors(draw, shape=(), min_norm=1e-3):
    v = draw(hnp.arrays(np.float64, tuple(shape) + (3,), elements=coord))
    assume(np.all(np.linalg.norm(v, axis=-1) > min_norm))
    return v


def points(shape):
    return hnp.arrays(np.float64, tuple(shape) + (3,), elements=coord)


batch_shapes = hnp.array_shapes(min_dims=0, max_dims=2, min_side=1, max_side=3)


def rotations(shape=()):
    return quats(shape).map(G.quat_to_matrix)


def assert_rotation(R, atol=1e-9):
    R = np.asarray(R)
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, eye, atol=atol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=atol)


def assert_same_rotation(qa, qb, atol=1e-9):
    """Quaternions equal up to sign."""
    dot = np.abs(np.sum(np.asarray(qa) * np.asarray(qb), axis=-1))
    np.testing.assert_allclose(dot, 1.0, atol=atol)
