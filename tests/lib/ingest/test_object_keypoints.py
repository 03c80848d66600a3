"""Tests of demoforge.lib.ingest.object_keypoints: 2D annotation + depth -> world points."""


import numpy as np
import pytest

from demoforge.lib.ingest.alignment import project
from demoforge.lib.geometry import make_transform, random_rotations, transform_inverse, transform_points
from demoforge.lib.ingest.object_keypoints import backproject_keypoints, backproject_keypoints_detailed
from tests.support.paths import CHECKOUT_SHARED_DATA

DEXCAP = CHECKOUT_SHARED_DATA / "rgbd" / "dexcap_frame_0"
DEXCAP_K = np.array([[898.2010498046875, 0, 657.4981079101562], [0, 897.86669921875, 364.30950927734375], [0, 0, 1]])


def test_round_trip_on_synthetic_plane():
    K = np.array([[570.0, 0, 319.5], [0, 570.0, 239.5], [0, 0, 1]])
    T_wc = make_transform(random_rotations(1, 0)[0], np.array([0.1, -0.4, 0.9]))
    depth = np.full((480, 640), 0.7)
    depth[100:110, 100:110] = 0.0  # a hole
    uv = np.array([[320.0, 240.0], [10.2, 470.4], [105.0, 105.0], [700.0, 10.0], [np.nan, 1.0]])
    pw, valid = backproject_keypoints(uv, depth, K, T_wc)
    assert valid.tolist() == [True, True, False, False, False]
    assert np.isnan(pw[~valid]).all()
    pc = transform_points(transform_inverse(T_wc), pw[valid])
    np.testing.assert_allclose(pc[:, 2], 0.7)
    np.testing.assert_allclose(project(pc, K), uv[valid], atol=1e-9)
    r = backproject_keypoints_detailed(uv, depth, K, T_wc)
    assert r.reasons == ["ok", "ok", "no valid depth in the window", "outside the image", "uv not finite"]


@pytest.mark.skipif(not (DEXCAP / "depth_image.png").exists(), reason="../shared/data/rgbd/dexcap_frame_0 absent: the real RGB-D frame comes with "
                    "the shared data folder (../shared/data beside the checkout)")
def test_real_dexcap_frame_round_trip_and_zeros():
    import cv2

    raw = cv2.imread(str(DEXCAP / "depth_image.png"), cv2.IMREAD_UNCHANGED)
    T_wc = np.eye(4)
    zeros = np.argwhere(raw == 0)
    r0, c0 = zeros[len(zeros) // 2]
    uv = np.array([[640.0, 360.0], [c0, r0], [1000.4, 200.6]])
    r = backproject_keypoints_detailed(uv, raw, DEXCAP_K, T_wc, window=5, min_valid=1, depth_scale=0.001)
    for (u, v), z, ok in zip(uv, r.depth, r.valid):
        rr, cc = int(round(v)), int(round(u))
        win = raw[rr - 2:rr + 3, cc - 2:cc + 3].astype(float)
        vals = win[win > 0] / 1000.0
        if vals.size:
            assert ok and z == pytest.approx(np.median(vals)) and z > 0
        else:
            assert not ok and np.isnan(z)
    ok = r.valid
    np.testing.assert_allclose(project(r.points_camera[ok], DEXCAP_K), uv[ok], atol=1e-9)
    np.testing.assert_allclose(r.points_world[ok], r.points_camera[ok])
