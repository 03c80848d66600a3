"""Property tests for demoforge.lib.geometry.rotations: quaternions, rotations between vectors, random and yaw
rotations (hypothesis + scipy references)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial.transform import Rotation, Slerp

from demoforge.lib import geometry as G
from tests.support.geometry_strategies import (
    FAST, assert_rotation, assert_same_rotation, batch_shapes, quats, unit_coord, vectors,
)


# ----------------------------------------------------------------------------- quaternions


@FAST
@given(batch_shapes.flatmap(lambda s: quats(s)))
def test_quat_matrix_round_trip_and_orthonormal(q):
    R = G.quat_to_matrix(q)
    assert R.shape == q.shape[:-1] + (3, 3)
    assert_rotation(R)
    q2 = G.matrix_to_quat(R)
    assert q2.shape == q.shape
    assert np.all(q2[..., 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q2, axis=-1), 1.0, atol=1e-12)
    assert_same_rotation(q, q2)
    np.testing.assert_allclose(G.quat_to_matrix(q2), R, atol=1e-12)


@FAST
@given(quats((5,)))
def test_quat_matrix_matches_scipy(q):
    np.testing.assert_allclose(G.quat_to_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)
    R = Rotation.from_quat(q).as_matrix()
    assert_same_rotation(G.matrix_to_quat(R), Rotation.from_matrix(R).as_quat(), atol=1e-12)


def test_matrix_to_quat_near_pi_rotations():
    # trace ~ -1: the case where the naive w-pivot formula fails
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3.0]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for angle in (np.pi, np.pi - 1e-9, np.pi - 1e-4):
        rv = axes * angle
        R = Rotation.from_rotvec(rv).as_matrix()
        q = G.matrix_to_quat(R)
        assert_same_rotation(q, Rotation.from_rotvec(rv).as_quat(), atol=1e-12)
        np.testing.assert_allclose(G.quat_to_matrix(q), R, atol=1e-12)


@FAST
@given(batch_shapes.flatmap(lambda s: st.tuples(quats(s), quats(s))))
def test_quat_multiply_matches_matrix_product_and_scipy(ab):
    a, b = ab
    ab_q = G.quat_multiply(a, b)
    np.testing.assert_allclose(G.quat_to_matrix(ab_q), G.quat_to_matrix(a) @ G.quat_to_matrix(b), atol=1e-12)
    ref = (Rotation.from_quat(a.reshape(-1, 4)) * Rotation.from_quat(b.reshape(-1, 4))).as_quat()
    assert_same_rotation(ab_q.reshape(-1, 4), ref, atol=1e-12)


@FAST
@given(quats((4,)), quats(()))
def test_quat_multiply_broadcasts(a, b):
    out = G.quat_multiply(a, b)
    assert out.shape == (4, 4)
    for i in range(4):
        np.testing.assert_allclose(out[i], G.quat_multiply(a[i], b), atol=0)


@FAST
@given(quats((3,)))
def test_conjugate_is_inverse(q):
    ident = G.quat_multiply(q, G.quat_conjugate(q))
    np.testing.assert_allclose(ident, np.tile([0, 0, 0, 1.0], (3, 1)), atol=1e-12)
    np.testing.assert_allclose(G.quat_to_matrix(G.quat_conjugate(q)), np.swapaxes(G.quat_to_matrix(q), -1, -2),
                               atol=1e-12)


@FAST
@given(hnp.arrays(np.float64, (3, 4), elements=unit_coord))
def test_quat_normalize_and_canonical(raw):
    assume(np.all(np.linalg.norm(raw, axis=-1) > 1e-6))
    q = G.quat_normalize(raw)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(q * np.linalg.norm(raw, axis=-1, keepdims=True), raw, atol=1e-12)
    c = G.quat_canonical(q)
    assert np.all(c[:, 3] >= 0)
    assert_same_rotation(c, q)


def test_quat_normalize_errors_count_bad_rows():
    q = np.array([[0, 0, 0, 1.0], [0, 0, 0, 0], [np.nan, 0, 0, 1], [1, 0, 0, np.inf]])
    with pytest.raises(ValueError, match="3 of 4"):
        G.quat_normalize(q)
    with pytest.raises(ValueError):
        G.quat_to_matrix([0, 0, 0, 0])
    with pytest.raises(ValueError):
        G.quat_normalize([1.0, 0, 0])  # wrong shape


@FAST
@given(quats((4,)), quats((4,)), st.sampled_from([1.0, -1.0]), st.sampled_from([1.0, -1.0]))
def test_quat_angle(a, b, sa, sb):
    ang = G.quat_angle(sa * a, sb * b)
    ref = (Rotation.from_quat(a).inv() * Rotation.from_quat(b)).magnitude()
    np.testing.assert_allclose(ang, ref, atol=1e-9)
    assert np.all((ang >= 0) & (ang <= np.pi + 1e-12))
    np.testing.assert_allclose(G.quat_angle(a, a), 0.0, atol=1e-7)
    np.testing.assert_allclose(G.quat_angle(a, b), G.quat_angle(b, a), atol=1e-12)


@FAST
@given(hnp.arrays(np.float64, (5, 3), elements=st.floats(-1.5, 1.5)))
def test_quat_exp_log_round_trip(v):
    q = G.quat_exp(v)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(G.quat_log(q), v, atol=1e-10)
    # exp of the half rotation vector is the scipy rotation of the full rotation vector
    assert_same_rotation(q, Rotation.from_rotvec(2 * v).as_quat(), atol=1e-12)


@FAST
@given(quats((4,)), quats((4,)), st.floats(0.0, 1.0))
def test_quat_slerp_matches_scipy(a, b, t):
    ours = G.quat_slerp(a, b, t)
    for i in range(4):
        ref = Slerp([0.0, 1.0], Rotation.from_quat([a[i], b[i]]))([t]).as_quat()[0]
        assert_same_rotation(ours[i], ref, atol=1e-9)
    np.testing.assert_allclose(G.quat_slerp(a, b, 0.0), a, rtol=0, atol=1e-15)
    assert_same_rotation(G.quat_slerp(a, b, 1.0), b, atol=1e-12)


@FAST
@given(batch_shapes.flatmap(lambda s: quats(s)))
def test_wxyz_round_trip(q):
    w = G.xyzw_to_wxyz(q)
    np.testing.assert_array_equal(w[..., 0], q[..., 3])
    np.testing.assert_array_equal(w[..., 1:], q[..., :3])
    np.testing.assert_array_equal(G.wxyz_to_xyzw(w), q)


# ----------------------------------------------------------------------------- vectors


@FAST
@given(vectors((4,)), vectors((4,)))
def test_skew_is_cross_product(v, w):
    S = G.skew(v)
    np.testing.assert_allclose((S @ w[..., None])[..., 0], np.cross(v, w), atol=1e-10)
    np.testing.assert_array_equal(S, -np.swapaxes(S, -1, -2))


def _check_maps(a, b, R, atol=1e-9):
    ah = a / np.linalg.norm(a, axis=-1, keepdims=True)
    bh = b / np.linalg.norm(b, axis=-1, keepdims=True)
    assert_rotation(R, atol=atol)
    np.testing.assert_allclose((R @ ah[..., None])[..., 0], bh, atol=atol)
    assert np.isfinite(R).all()


@FAST
@given(vectors((6,)), vectors((6,)))
def test_rotation_between_vectors_generic(a, b):
    R = G.rotation_between_vectors(a, b)
    _check_maps(a, b, R)
    # equals the Rodrigues formula where it is well conditioned
    ah = a / np.linalg.norm(a, axis=-1, keepdims=True)
    bh = b / np.linalg.norm(b, axis=-1, keepdims=True)
    v = np.cross(ah, bh)
    c = np.sum(ah * bh, axis=-1)
    ok = c > -0.9
    K = G.skew(v[ok])
    s2 = np.sum(v[ok] ** 2, axis=-1)
    fac = np.where(s2 > 1e-20, (1 - c[ok]) / np.where(s2 > 1e-20, s2, 1.0), 0.5)
    rod = np.eye(3) + K + K @ K * fac[:, None, None]
    np.testing.assert_allclose(R[ok], rod, atol=1e-8)
    # minimal rotation: the angle equals the angle between the vectors
    ang = Rotation.from_matrix(R).magnitude()
    np.testing.assert_allclose(ang, np.arccos(np.clip(c, -1, 1)), atol=1e-6)


@FAST
@given(vectors(), st.floats(0.01, 100.0), st.floats(0.01, 100.0))
def test_rotation_between_vectors_parallel_and_antiparallel(a, s1, s2):
    R = G.rotation_between_vectors(s1 * a, s2 * a)
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    R = G.rotation_between_vectors(s1 * a, -s2 * a)
    _check_maps(a, -a, R, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(R).magnitude(), np.pi, atol=1e-6)
    # deterministic
    np.testing.assert_array_equal(R, G.rotation_between_vectors(s1 * a, -s2 * a))


@FAST
@given(vectors(), vectors(), st.sampled_from([1e-3, 1e-6, 1e-9, 1e-12, 1e-15]))
def test_rotation_between_vectors_nearly_antiparallel(a, perturb, eps):
    b = -a / np.linalg.norm(a) + eps * perturb / np.linalg.norm(perturb)
    assume(np.linalg.norm(b) > 1e-3)
    R = G.rotation_between_vectors(a, b)
    _check_maps(a, b, R, atol=1e-9)


def test_rotation_between_vectors_axes_and_batch():
    e = np.eye(3)
    R = G.rotation_between_vectors(e[:, None, :], e[None, :, :])
    assert R.shape == (3, 3, 3, 3)
    _check_maps(np.broadcast_to(e[:, None, :], (3, 3, 3)), np.broadcast_to(e[None], (3, 3, 3)), R, atol=1e-15)


def test_rotation_between_vectors_errors():
    with pytest.raises(ValueError):
        G.rotation_between_vectors([0, 0, 0], [1, 0, 0])
    with pytest.raises(ValueError):
        G.rotation_between_vectors([[1, 0, 0], [1, 0, 0]], [[1, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError):
        G.rotation_between_vectors([np.nan, 0, 0], [1, 0, 0])


# ----------------------------------------------------------------------------- sampling


def test_random_rotations_uniform():
    R = G.random_rotations(20000, np.random.default_rng(6))
    assert R.shape == (20000, 3, 3)
    assert_rotation(R)
    # Haar measure: E[R] = 0, and the rotation angle has density (1 - cos a) / pi -> E[cos a] = -1/2... of trace
    np.testing.assert_allclose(R.mean(axis=0), 0.0, atol=0.03)
    tr = np.trace(R, axis1=-2, axis2=-1)  # = 1 + 2 cos(angle); E = 0 for Haar
    assert abs(tr.mean()) < 0.05
    np.testing.assert_array_equal(R, G.random_rotations(20000, 6))


@FAST
@given(hnp.arrays(np.float64, (5,), elements=st.floats(-10, 10)))
def test_yaw_rotation(theta):
    R = G.yaw_rotation(theta)
    assert_rotation(R)
    np.testing.assert_allclose(R, Rotation.from_euler("z", theta[:, None]).as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(R[..., 2, :], np.broadcast_to([0, 0, 1.0], (5, 3)))
