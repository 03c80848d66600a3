"""Property tests for demoforge.lib.geometry (hypothesis + scipy references)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from demoforge.lib import geometry as G

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ----------------------------------------------------------------------------- strategies

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


# ----------------------------------------------------------------------------- SE(3)


@st.composite
def transforms(draw, shape=()):
    R = draw(rotations(shape))
    t = draw(points(shape))
    return G.make_transform(R, t)


@FAST
@given(batch_shapes.flatmap(lambda s: transforms(s)))
def test_transform_inverse(T):
    Ti = G.transform_inverse(T)
    eye = np.broadcast_to(np.eye(4), T.shape)
    np.testing.assert_allclose(G.transform_compose(Ti, T), eye, atol=1e-12)
    np.testing.assert_allclose(G.transform_compose(T, Ti), eye, atol=1e-12)
    np.testing.assert_allclose(Ti, np.linalg.inv(T), atol=1e-10)


@FAST
@given(transforms((2,)), transforms((2,)), points((2, 5)))
def test_transform_compose_and_points(A, B, p):
    AB = G.transform_compose(A, B)
    np.testing.assert_allclose(AB, A @ B, atol=0)
    # point sets (..., N, 3)
    out = G.transform_points(AB, p)
    assert out.shape == (2, 5, 3)
    homog = np.concatenate([p, np.ones((2, 5, 1))], axis=-1)
    ref = np.einsum("bij,bnj->bni", AB, homog)[..., :3]
    np.testing.assert_allclose(out, ref, atol=1e-10)
    np.testing.assert_allclose(out, G.transform_points(A, G.transform_points(B, p)), atol=1e-10)
    # single points (..., 3), one per transform
    single = G.transform_points(AB, p[:, 0])
    assert single.shape == (2, 3)
    np.testing.assert_allclose(single, ref[:, 0], atol=1e-10)
    # one transform, many points
    one = G.transform_points(A[0], p)
    np.testing.assert_allclose(one, p @ A[0, :3, :3].T + A[0, :3, 3], atol=1e-12)


@FAST
@given(batch_shapes.flatmap(lambda s: st.tuples(points(s), quats(s), hnp.arrays(np.float64, s, elements=st.sampled_from([0.0, 1.0, 0.5])))))
def test_pose8_round_trip(args):
    pos, q, g = args
    p8 = np.concatenate([pos, q, g[..., None]], axis=-1)
    T, g2 = G.pose8_to_transform(p8)
    assert T.shape == pos.shape[:-1] + (4, 4)
    np.testing.assert_array_equal(g2, g)
    np.testing.assert_allclose(T[..., :3, 3], pos, atol=0)
    np.testing.assert_allclose(T[..., :3, :3], Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(T.shape[:-2] + (3, 3)), atol=1e-12)
    back = G.transform_to_pose8(T, g2)
    np.testing.assert_allclose(back[..., :3], pos, atol=0)
    np.testing.assert_array_equal(back[..., 7], g)
    assert_same_rotation(back[..., 3:7], q, atol=1e-12)
    assert np.all(back[..., 6] >= 0)
    p7 = G.transform_to_pose7(T)
    np.testing.assert_allclose(G.pose7_to_transform(p7), T, atol=1e-12)


def test_transform_to_pose8_default_open_and_shapes():
    T = np.broadcast_to(np.eye(4), (2, 3, 4, 4))
    p8 = G.transform_to_pose8(T)
    assert p8.shape == (2, 3, 8)
    np.testing.assert_array_equal(p8[..., 7], 1.0)
    np.testing.assert_array_equal(p8[0, 0], [0, 0, 0, 0, 0, 0, 1, 1])
    with pytest.raises(ValueError):
        G.pose8_to_transform(np.zeros(7))


# ----------------------------------------------------------------------------- reflection

planes = st.tuples(vectors(min_norm=0.1), st.floats(-2.0, 2.0))


@FAST
@given(points((7,)), planes)
def test_reflect_points(p, plane):
    n, d = plane
    nh = n / np.linalg.norm(n)
    r = G.reflect_points(p, n, d)
    # symmetric: midpoint on the plane, displacement along the normal
    mid = 0.5 * (p + r)
    np.testing.assert_allclose(mid @ nh, d, atol=1e-9)
    np.testing.assert_allclose(np.cross(r - p, nh), 0.0, atol=1e-9)
    np.testing.assert_allclose(G.reflect_points(r, n, d), p, atol=1e-9)
    # matches the Householder matrix for planes through the origin
    np.testing.assert_allclose(G.reflect_points(p, n), p @ G.reflection_matrix(n).T, atol=1e-10)


def test_reflect_points_default_plane_is_yz():
    p = np.array([[0.3, -0.2, 0.5], [-1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(G.reflect_points(p), p * [-1, 1, 1])
    np.testing.assert_array_equal(G.reflection_matrix(), np.diag([-1.0, 1, 1]))
    with pytest.raises(ValueError):
        G.reflection_matrix([0, 0, 0])


@FAST
@given(rotations((5,)), vectors(min_norm=0.1), st.sampled_from([0, 1, 2]))
def test_reflect_rotation(R, n, k):
    M = G.reflection_matrix(n)
    assert np.linalg.det(M) == pytest.approx(-1.0)
    Rr = G.reflect_rotation(R, n, flip_column=k)
    assert_rotation(Rr)
    MR = M @ R
    others = [j for j in range(3) if j != k]
    np.testing.assert_allclose(Rr[..., :, others], MR[..., :, others], atol=1e-12)
    np.testing.assert_allclose(Rr[..., :, k], -MR[..., :, k], atol=1e-12)
    np.testing.assert_allclose(G.reflect_rotation(Rr, n, flip_column=k), R, atol=1e-12)
    # quaternion form agrees and is an exact involution
    q = G.matrix_to_quat(R)
    qr = G.reflect_quat(q, n, flip_column=k)
    np.testing.assert_allclose(G.quat_to_matrix(qr), Rr, atol=1e-12)
    np.testing.assert_allclose(G.reflect_quat(qr, n, flip_column=k), q, atol=1e-15)


def test_reflect_rotation_default_gripper_semantics():
    # Gripper on the right side approaching along +x, closing along +y: mirrored approaches along -x.
    R = np.stack([[0, 1.0, 0], [0, 0, 1.0], [1.0, 0, 0]], axis=-1)  # columns x=(0,1,0), y=(0,0,1), z=(1,0,0)
    assert np.linalg.det(R) == pytest.approx(1.0)
    Rr = G.reflect_rotation(R)
    np.testing.assert_allclose(Rr[:, 2], [-1, 0, 0])  # approach mirrored
    np.testing.assert_allclose(Rr[:, 0], [0, 1, 0])  # closing direction mirrored (unchanged by x-mirror)
    np.testing.assert_allclose(Rr[:, 1], np.cross(Rr[:, 2], Rr[:, 0]))  # y = z cross x
    with pytest.raises(ValueError):
        G.reflect_rotation(R, flip_column=3)


@FAST
@given(transforms((4,)), planes, points((4, 6)))
def test_reflect_transform(T, plane, p):
    n, d = plane
    Tr = G.reflect_transform(T, n, d)
    assert_rotation(Tr[..., :3, :3])
    np.testing.assert_allclose(G.reflect_transform(Tr, n, d), T, atol=1e-9)
    np.testing.assert_allclose(Tr[..., :3, 3], G.reflect_points(T[..., :3, 3], n, d), atol=0)
    # points fixed in the gripper frame (with their y coordinate negated) map to the mirrored points
    local = p * [1, -1, 1]
    np.testing.assert_allclose(G.transform_points(Tr, local), G.reflect_points(G.transform_points(T, p), n, d),
                               atol=1e-9)


@FAST
@given(points((2, 3)), quats((2, 3)), planes)
def test_reflect_pose8(pos, q, plane):
    n, d = plane
    g = np.array([[0.0, 1.0, 1.0], [1.0, 0.0, 0.5]])
    p8 = np.concatenate([pos, q, g[..., None]], axis=-1)
    r8 = G.reflect_pose8(p8, n, d)
    assert r8.shape == p8.shape
    np.testing.assert_array_equal(r8[..., 7], g)
    T, _ = G.pose8_to_transform(p8)
    Tr, _ = G.pose8_to_transform(r8)
    np.testing.assert_allclose(Tr, G.reflect_transform(T, n, d), atol=1e-10)
    np.testing.assert_allclose(G.reflect_pose8(r8, n, d), p8, atol=1e-9)


# ----------------------------------------------------------------------------- umeyama


@st.composite
def similarity_problem(draw, batch=()):
    n = draw(st.integers(3, 12))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    spread = draw(st.floats(0.05, 5.0))
    offset = draw(points(()))
    src = offset + spread * rng.standard_normal(tuple(batch) + (n, 3))
    centred = src - src.mean(axis=-2, keepdims=True)
    # not collinear (rank >= 2 determines the rotation; n = 3 is always planar)
    sv = np.linalg.svd(centred, compute_uv=False)
    assume(np.all(sv[..., 1] > 0.05 * spread))
    R = draw(rotations(batch))
    t = draw(points(batch))
    s = draw(hnp.arrays(np.float64, tuple(batch), elements=st.floats(0.5, 2.0)))
    return src, s, R, t


@SLOW
@given(similarity_problem())
def test_umeyama_recovers_similarity(prob):
    src, s, R, t = prob
    dst = s * src @ R.T + t
    s2, R2, t2 = G.umeyama(src, dst)
    np.testing.assert_allclose(s2, s, rtol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-8)
    np.testing.assert_allclose(G.apply_similarity(s2, R2, t2, src), dst, atol=1e-8)


@SLOW
@given(similarity_problem())
def test_kabsch_recovers_rigid(prob):
    src, _, R, t = prob
    dst = src @ R.T + t
    s2, R2, t2 = G.umeyama(src, dst, with_scale=False)
    assert s2 == 1.0
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-8)


@SLOW
@given(similarity_problem(batch=(2, 3)), st.floats(0.0, 0.5))
def test_umeyama_batched_equals_loop(prob, noise):
    src, s, R, t = prob
    rng = np.random.default_rng(0)
    dst = s[..., None, None] * src @ np.swapaxes(R, -1, -2) + t[..., None, :]
    dst = dst + noise * rng.standard_normal(dst.shape)
    w = rng.uniform(0.5, 2.0, src.shape[:-1])
    for kwargs in ({}, {"with_scale": False}, {"weights": w}):
        sb, Rb, tb = G.umeyama(src, dst, **kwargs)
        assert sb.shape == (2, 3) and Rb.shape == (2, 3, 3, 3) and tb.shape == (2, 3, 3)
        assert_rotation(Rb)
        for i in range(2):
            for j in range(3):
                kw = dict(kwargs)
                if "weights" in kw:
                    kw["weights"] = w[i, j]
                si, Ri, ti = G.umeyama(src[i, j], dst[i, j], **kw)
                np.testing.assert_allclose(sb[i, j], si, rtol=1e-10)
                np.testing.assert_allclose(Rb[i, j], Ri, atol=1e-10)
                np.testing.assert_allclose(tb[i, j], ti, atol=1e-9)


@SLOW
@given(similarity_problem())
def test_umeyama_reflected_target_still_proper(prob):
    src, s, R, t = prob
    dst = G.reflect_points(s * src @ R.T + t)  # a mirror image: best fit must still be a rotation
    _, R2, _ = G.umeyama(src, dst)
    assert_rotation(R2)


def test_umeyama_weights_ignore_outlier():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(10, 3))
    R = G.random_rotations(1, rng)[0]
    dst = 1.5 * src @ R.T + [1, 2, 3]
    dst[0] += 100.0
    w = np.ones(10)
    w[0] = 0.0
    s, R2, t = G.umeyama(src, dst, weights=w)
    np.testing.assert_allclose([s], [1.5], rtol=1e-10)
    np.testing.assert_allclose(R2, R, atol=1e-10)


def test_umeyama_errors():
    p = np.random.default_rng(2).normal(size=(5, 3))
    with pytest.raises(ValueError, match="at least 3"):
        G.umeyama(p[:2], p[:2])
    with pytest.raises(ValueError, match="degenerate"):
        G.umeyama(np.tile([1.0, 2.0, 3.0], (5, 1)), p)
    with pytest.raises(ValueError):
        G.umeyama(p, p[:4])
    with pytest.raises(ValueError):
        G.umeyama(p, p, weights=-np.ones(5))
    with pytest.raises(ValueError):
        G.umeyama(p, p, weights=np.array([1.0, 1, 0, 0, 0]))
    bad = p.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        G.umeyama(bad, p)


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
