"""Property tests for demoforge.lib.geometry.transforms: SE(3) transforms, poses, reflections (hypothesis + scipy
references)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial.transform import Rotation

from demoforge.lib import geometry as G
from tests.support.geometry_strategies import (
    FAST, assert_rotation, assert_same_rotation, batch_shapes, points, quats, rotations, vectors,
)


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
