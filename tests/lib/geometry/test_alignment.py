"""Property tests for demoforge.lib.geometry.alignment: Umeyama / Kabsch alignment (hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from demoforge.lib import geometry as G
from tests.support.geometry_strategies import SLOW, assert_rotation, points, rotations


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
