"""Property tests for demoforge.lib.geometry.interpolation: pose interpolation and cubic transitions (hypothesis +
scipy references)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from demoforge.lib import geometry as G
from tests.support.geometry_strategies import SLOW, assert_same_rotation, points, quats


# ----------------------------------------------------------------------------- interpolation


@st.composite
def keyframes(draw, extra=()):
    k = draw(st.integers(2, 7))
    gaps = draw(hnp.arrays(np.float64, (k - 1,), elements=st.floats(0.1, 2.0)))
    t0 = draw(st.floats(-5.0, 5.0))
    times = t0 + np.concatenate([[0.0], np.cumsum(gaps)])
    pos = draw(points((k,) + tuple(extra)))
    q = draw(quats((k,) + tuple(extra)))
    # keep consecutive keyframes less than ~170 degrees apart so the geodesic is well defined
    ang = G.quat_angle(q[1:], q[:-1])
    assume(np.all(ang < np.deg2rad(170)))
    return times, pos, q


@SLOW
@given(keyframes(), st.sampled_from(["slerp", "squad"]), st.sampled_from(["cubic", "linear"]))
def test_interpolation_hits_keyframes(kf, rot, posm):
    times, pos, q = kf
    P, Q = G.interpolate_poses(times, pos, q, times, rotation=rot, position=posm)
    assert P.shape == pos.shape and Q.shape == q.shape
    np.testing.assert_allclose(P, pos, atol=1e-9)
    assert_same_rotation(Q, q, atol=1e-12)
    # dense query: unit quaternions, hemisphere-continuous
    tq = np.linspace(times[0] - 1.0, times[-1] + 1.0, 301)
    P, Q = G.interpolate_poses(times, pos, q, tq, rotation=rot, position=posm)
    np.testing.assert_allclose(np.linalg.norm(Q, axis=-1), 1.0, atol=1e-12)
    assert np.all(np.sum(Q[1:] * Q[:-1], axis=-1) > 0)
    # clamping outside the range
    np.testing.assert_allclose(P[0], pos[0], atol=1e-9)
    np.testing.assert_allclose(P[-1], pos[-1], atol=1e-9)
    assert_same_rotation(Q[0], q[0], atol=1e-12)
    assert_same_rotation(Q[-1], q[-1], atol=1e-12)


@SLOW
@given(keyframes(), st.floats(0.0, 1.0))
def test_interpolation_slerp_matches_scipy(kf, frac):
    times, pos, q = kf
    tq = times[0] + frac * (times[-1] - times[0]) + np.linspace(0, 0, 1)
    tq = np.concatenate([tq, np.linspace(times[0], times[-1], 17)])
    P, Q = G.interpolate_poses(times, pos, q, tq, rotation="slerp", position="cubic")
    assert_same_rotation(Q, Slerp(times, Rotation.from_quat(q))(tq).as_quat(), atol=1e-9)
    np.testing.assert_allclose(P, CubicSpline(times, pos, axis=0)(tq), atol=1e-9)


@SLOW
@given(keyframes(), points(()), points(()), st.sampled_from(["cubic", "linear"]))
def test_interpolation_reproduces_linear_motion(kf, p0, v, posm):
    times, _, _ = kf
    v = v / 10.0
    pos = p0 + times[:, None] * v
    # constant angular velocity about a fixed axis: rotation angle linear in time
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    omega = 0.4
    q = Rotation.from_rotvec(np.outer(times - times[0], axis * omega)).as_quat()
    q[1::2] *= -1  # sign flips must not matter
    tq = np.linspace(times[0], times[-1], 53)
    for rot in ("slerp", "squad"):
        P, Q = G.interpolate_poses(times, pos, q, tq, rotation=rot, position=posm)
        np.testing.assert_allclose(P, p0 + tq[:, None] * v, atol=1e-9)
        ref = Rotation.from_rotvec(np.outer(tq - times[0], axis * omega)).as_quat()
        assert_same_rotation(Q, ref, atol=1e-9)


def test_squad_c1_at_interior_keyframes():
    rng = np.random.default_rng(3)
    times = np.array([0.0, 0.7, 1.2, 2.5, 3.0])
    q = G.quat_multiply(G.random_quaternions(1, rng), G.quat_exp(rng.normal(scale=0.4, size=(5, 3))))
    h = 1e-6
    for tk in times[1:-1]:
        _, Q = G.interpolate_poses(times, np.zeros((5, 3)), q, [tk - h, tk, tk + h], rotation="squad")
        w_left = 2 * G.quat_log(G.quat_multiply(G.quat_conjugate(Q[0]), Q[1])) / h
        w_right = 2 * G.quat_log(G.quat_multiply(G.quat_conjugate(Q[1]), Q[2])) / h
        np.testing.assert_allclose(w_left, w_right, atol=1e-4 * (1 + np.linalg.norm(w_left)))
    # slerp, by contrast, has a kink there (sanity check that the test can fail)
    _, Q = G.interpolate_poses(times, np.zeros((5, 3)), q, [times[2] - h, times[2], times[2] + h])
    w_left = G.quat_log(G.quat_multiply(G.quat_conjugate(Q[0]), Q[1])) / h
    w_right = G.quat_log(G.quat_multiply(G.quat_conjugate(Q[1]), Q[2])) / h
    assert np.linalg.norm(w_left - w_right) > 1e-2


def test_interpolation_extra_axes_and_errors():
    rng = np.random.default_rng(4)
    times = np.array([0.0, 1.0, 2.0, 4.0])
    pos = rng.normal(size=(4, 2, 3))
    q = G.random_quaternions(8, rng).reshape(4, 2, 4)
    tq = np.linspace(-1, 5, 11)
    P, Q = G.interpolate_poses(times, pos, q, tq, rotation="squad")
    assert P.shape == (11, 2, 3) and Q.shape == (11, 2, 4)
    for arm in range(2):
        Pa, Qa = G.interpolate_poses(times, pos[:, arm], q[:, arm], tq, rotation="squad")
        np.testing.assert_allclose(P[:, arm], Pa, atol=1e-12)
        np.testing.assert_allclose(Q[:, arm], Qa, atol=1e-12)
    P1, Q1 = G.interpolate_poses([1.0], pos[:1], q[:1], tq)
    np.testing.assert_allclose(P1, np.broadcast_to(pos[:1], (11, 2, 3)))
    with pytest.raises(ValueError, match="increasing"):
        G.interpolate_poses([0.0, 0.0, 1.0], pos[:3], q[:3], tq)
    with pytest.raises(ValueError):
        G.interpolate_poses(times, pos[:3], q, tq)
    with pytest.raises(ValueError):
        G.interpolate_poses(times, pos, q, tq, rotation="bogus")
    with pytest.raises(ValueError):
        G.interpolate_poses(times, pos, q, tq, position="quintic")


@SLOW
@given(points(()), quats(()), points(()), quats(()), st.integers(50, 300))
def test_cubic_transition(p0, q0, p1, q1, n):
    P, Q = G.cubic_transition(p0, q0, p1, q1, n)
    assert P.shape == (n, 3) and Q.shape == (n, 4)
    np.testing.assert_array_equal(P[0], p0)
    np.testing.assert_array_equal(P[-1], p1)
    np.testing.assert_allclose(Q[0], q0, atol=1e-15)
    assert_same_rotation(Q[-1], q1, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(Q, axis=-1), 1.0, atol=1e-12)
    # zero velocity at both ends: the first/last step is O(1/n^2) of the distance, not O(1/n)
    dist = np.linalg.norm(p1 - p0)
    bound = 3.0 / (n - 1) ** 2
    assert np.linalg.norm(P[1] - P[0]) <= bound * dist + 1e-12
    assert np.linalg.norm(P[-1] - P[-2]) <= bound * dist + 1e-12
    ang = G.quat_angle(q0, q1)
    assert G.quat_angle(Q[0], Q[1]) <= bound * ang + 1e-7
    assert G.quat_angle(Q[-2], Q[-1]) <= bound * ang + 1e-7
    # monotone progress along the straight line and the geodesic
    along = (P - p0) @ (p1 - p0)
    assert np.all(np.diff(along) >= -1e-9)
    assert np.all(np.diff(G.quat_angle(q0, Q)) >= -1e-7)
    # the peak speed is the smoothstep's 1.5x the average
    if dist > 1e-3:
        step = np.linalg.norm(np.diff(P, axis=0), axis=-1).max()
        assert step == pytest.approx(1.5 * dist / (n - 1), rel=0.02)


def test_cubic_transition_batched_and_errors():
    rng = np.random.default_rng(5)
    p0, p1 = rng.normal(size=(2, 2, 3))
    q0, q1 = G.random_quaternions(4, rng).reshape(2, 2, 4)
    P, Q = G.cubic_transition(p0, q0, p1, q1, 10)
    assert P.shape == (10, 2, 3) and Q.shape == (10, 2, 4)
    for arm in range(2):
        Pa, Qa = G.cubic_transition(p0[arm], q0[arm], p1[arm], q1[arm], 10)
        np.testing.assert_allclose(P[:, arm], Pa, atol=1e-15)
        np.testing.assert_allclose(Q[:, arm], Qa, atol=1e-15)
    with pytest.raises(ValueError):
        G.cubic_transition(p0, q0, p1, q1, 1)
    with pytest.raises(ValueError):
        G.cubic_transition(p0, np.zeros(4), p1, q1, 5)
