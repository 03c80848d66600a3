"""The kinematic hand: pinch constraint, the thesis's mapping, mirror symmetry, rigid bones."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from demoforge.lib.perception.hand_model import (
    HAND_BONES, HandStyle, bone_lengths, hand_capsules, hand_from_pinch, hand_joints, joint_radii,
    pinch_from_joints, sample_style,
)


def _random_rotation(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _random_pinches(rng, n):
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        T[i, :3, :3] = _random_rotation(rng)
    T[:, :3, 3] = rng.uniform(-0.6, 0.6, (n, 3))
    return T


def _mirror_pinch(T):
    """Mirror a pinch frame in the x = 0 plane: position and x, z axes mirror, y = z x x follows."""
    M = np.diag([-1.0, 1.0, 1.0])
    out = T.copy()
    out[..., :3, :3] = M @ T[..., :3, :3] @ np.diag([1.0, -1.0, 1.0])
    out[..., :3, 3] = T[..., :3, 3] * [-1, 1, 1]
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), side=st.sampled_from(["left", "right", 0, 1]),
       aperture=st.floats(0.0, 0.12))
def test_pinch_constraint_and_thesis_mapping(seed, side, aperture):
    rng = np.random.default_rng(seed)
    style = sample_style(rng)
    T = _random_pinches(rng, 8)
    a = np.full(8, aperture)
    a[1:] = rng.uniform(0.0, 0.12, 7)
    J, wrist = hand_from_pinch(T, a, side, style)
    assert J.shape == (8, 21, 3) and wrist.shape == (8, 4, 4)
    assert np.isfinite(J).all() and np.isfinite(wrist).all()
    o, x, z = T[:, :3, 3], T[:, :3, 0], T[:, :3, 2]
    # thumb tip at -a/2 x, index tip at +a/2 x (required < 1 mm; the construction is exact)
    assert np.linalg.norm(J[:, 4] - (o - a[:, None] / 2 * x), axis=-1).max() < 1e-9
    assert np.linalg.norm(J[:, 8] - (o + a[:, None] / 2 * x), axis=-1).max() < 1e-9
    # the base midpoint lies behind the pinch point on its -z axis
    b = 0.5 * (J[:, 0] + J[:, 1])
    d = o - b
    along = np.sum(d * z, axis=-1)
    assert (along > 0.03).all()
    assert np.linalg.norm(d - along[:, None] * z, axis=-1).max() < 1e-9
    # the thesis's mapping recovers the frame and the aperture
    T2, a2 = pinch_from_joints(J)
    assert np.abs(T2[:, :3, 3] - o).max() < 1e-9                      # < 1e-6 mm
    # z (approach) always; the full rotation where the tips are apart (x is undefined at a = 0)
    assert np.arccos(np.clip(np.sum(T2[:, :3, 2] * z, -1), -1, 1)).max() < 1e-6       # rad
    cosang = np.clip((np.trace(np.swapaxes(T2[:, :3, :3], -1, -2) @ T[:, :3, :3], axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    apart = a > 1e-4
    assert np.arccos(cosang[apart]).max(initial=0.0) < 1e-6                          # rad
    assert np.abs(a2 - a).max() < 1e-9
    # the wrist pose is a rigid transform
    R = wrist[:, :3, :3]
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)


def test_other_fingers_close_as_aperture_shrinks():
    T = np.eye(4)
    a = np.linspace(0.0, 0.1, 11)
    J, _ = hand_from_pinch(np.broadcast_to(T, (11, 4, 4)), a, "right")
    # curl of middle/ring/pinky: fingertip distance to the wrist shrinks as the fingers close
    for tip in (12, 16, 20):
        dist = np.linalg.norm(J[:, tip] - J[:, 0], axis=-1)
        assert np.all(np.diff(dist) >= -1e-12) and dist[-1] - dist[0] > 0.01


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_left_right_mirror_symmetry(seed):
    rng = np.random.default_rng(seed)
    style = sample_style(rng)
    T = _random_pinches(rng, 20)
    a = rng.uniform(0, 0.12, 20)
    Jr, _ = hand_from_pinch(T, a, "right", style)
    Jl, _ = hand_from_pinch(_mirror_pinch(T), a, "left", style)
    assert np.allclose(Jl, Jr * [-1, 1, 1], atol=1e-12)
    # forward kinematics too: mirrored wrist pose, same flexion
    W = np.tile(np.eye(4), (20, 1, 1))
    W[:, :3, :3] = T[:, :3, :3]
    W[:, :3, 3] = T[:, :3, 3]
    Wm = W.copy()
    Wm[:, :3, :3] = np.diag([-1.0, 1, 1]) @ W[:, :3, :3] @ np.diag([1.0, -1, 1])
    Wm[:, :3, 3] *= [-1, 1, 1]
    fl = rng.uniform(0, 1, (20, 5))
    assert np.allclose(hand_joints(Wm, fl, "left", style), hand_joints(W, fl, "right", style) * [-1, 1, 1])
    # and the anatomy: a right hand seen palm down, fingers along +y, has its thumb at -x
    Jr0 = hand_joints(np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]), 0.0, "right")
    assert Jr0[4, 0] < Jr0[20, 0]


def test_bone_lengths_constant_over_poses():
    rng = np.random.default_rng(5)
    style = HandStyle(scale=1.05, spread=1.3, flexion_bias=0.1)
    T = _random_pinches(rng, 200)
    a = rng.uniform(0, 0.14, 200)
    J, _ = hand_from_pinch(T, a, "left", style)
    L = bone_lengths(J)
    assert np.ptp(L, axis=0).max() < 1e-9
    fl = rng.uniform(0, 1, (200, 5))
    L2 = bone_lengths(hand_joints(T, fl, "left", style))
    assert np.ptp(L2, axis=0).max() < 1e-9
    # the same skeleton whether posed by flexion or by pinch
    assert np.allclose(L[0], L2[0])
    assert not np.isnan(J).any()


def test_adult_proportions_and_capsules():
    J = hand_joints(np.eye(4), 0.0, "right")
    palm = np.linalg.norm(J[9] - J[0])
    assert 0.09 <= palm <= 0.10
    for f, (m, t) in {"index": (5, 8), "middle": (9, 12), "ring": (13, 16), "pinky": (17, 20)}.items():
        length = np.linalg.norm(J[t] - J[m])
        assert 0.065 <= length <= 0.10, f
    thumb = sum(np.linalg.norm(J[i + 1] - J[i]) for i in (1, 2, 3))
    assert thumb < np.linalg.norm(J[12] - J[9]) + np.linalg.norm(J[9] - J[0])
    caps = hand_capsules()
    assert all(0.005 <= c.radius <= 0.013 for c in caps)
    assert joint_radii()[8] < joint_radii()[5]             # tapering to the tip
    assert len(HAND_BONES) == 21 and all(0 <= p < 21 and 0 <= c < 21 for p, c in HAND_BONES)
    # scale
    Js = hand_joints(np.eye(4), 0.3, 1, HandStyle(scale=1.1))
    assert np.isclose(np.linalg.norm(Js[9] - Js[0]), 1.1 * palm)


def test_sample_style_ranges():
    rng = np.random.default_rng(0)
    for _ in range(50):
        s = sample_style(rng)
        assert 0.9 <= s.scale <= 1.1 and 0.6 <= s.spread <= 1.4 and len(s.skin_rgba) == 4


def test_side_validation():
    with pytest.raises(ValueError):
        hand_joints(np.eye(4), 0.0, "middle")
