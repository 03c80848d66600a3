"""Take-level depth checks (demoforge.lib.ingest.depth_checks): empty, wrong-unit and misaligned depth are named."""


import numpy as np
import pytest

from demoforge.lib.ingest.depth_checks import DepthFrameStats, check_depth, frame_depth_stats
from tests.support.paths import CHECKOUT_SHARED_DATA

DEXCAP = CHECKOUT_SHARED_DATA / "rgbd" / "dexcap_frame_0"
K_DEXCAP = np.array([[898.2010498046875, 0, 657.4981079101562], [0, 897.86669921875, 364.30950927734375], [0, 0, 1]])


def _dexcap_mm() -> np.ndarray:
    import cv2

    p = DEXCAP / "depth_image.png"
    if not p.exists():
        pytest.skip(f"{p} absent: the real RGB-D frame comes with the shared data folder (../shared/data)")
    return cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)


def test_real_depth_frame_passes_and_its_unit_errors_are_named():
    mm = _dexcap_mm()
    good = check_depth(frame_depth_stats((mm * 0.001)[None], K_DEXCAP))
    assert good.ok and good.frames_with_depth == 1.0
    as_m = check_depth(frame_depth_stats(mm[None], K_DEXCAP))                 # millimetres read as metres
    assert as_m.problem == "unit_mm_read_as_m" and "depth_scale" in as_m.message and "\n" not in as_m.message
    as_mm = check_depth(frame_depth_stats((mm * 1e-6)[None], K_DEXCAP))        # metres read as millimetres
    assert as_mm.problem == "unit_m_read_as_mm" and "--accept-bad-depth" in as_mm.message


def test_all_zero_and_mostly_nan_depth():
    d = np.zeros((10, 48, 64))
    rep = check_depth(frame_depth_stats(d, K_DEXCAP / 20 * [[1], [1], [1]]))
    assert rep.problem == "empty_depth" and "10 of 10 frames" in rep.message and rep.frame_without_depth.all()
    d = np.full((10, 48, 64), np.nan)
    d[:3] = 0.7
    assert check_depth(frame_depth_stats(d, np.eye(3))).problem == "empty_depth"
    # depth in most frames, but none under the detected hands
    d[:] = 0.7
    det = np.ones((10, 2), bool)
    rep = check_depth(frame_depth_stats(d, np.eye(3)), det, np.zeros((10, 2), bool), np.full((10, 2), np.nan))
    assert rep.problem == "mostly_invalid_depth"


def test_table_plane_catches_depth_far_below_the_table():
    # camera 0.8 m above the table, looking straight down (camera z = world -z)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[2, 3] = 0.8
    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    d = np.full((2, 48, 64), 0.8)
    s = frame_depth_stats(d, K, T, step=4)
    assert (s.table_pixels > 0).all() and (s.beyond_table_fraction == 0).all()
    assert check_depth(s).ok
    s3 = frame_depth_stats(d * 5, K, T, step=4)       # 4 m: under a table 0.8 m away, within range
    assert (s3.beyond_table_fraction == 1).all() and check_depth(s3).problem == "unit_mm_read_as_m"


def test_hands_depth_against_their_size():
    stats = DepthFrameStats(np.ones(50), np.zeros(50), np.zeros(50), np.zeros(50), np.zeros(50, np.int64))
    det = np.ones((50, 2), bool)
    rng = np.random.default_rng(0)
    ok_ratio = np.exp(rng.normal(0, 0.1, (50, 2)))
    assert check_depth(stats, det, det, ok_ratio).ok
    assert check_depth(stats, det, det, ok_ratio * 1000).problem == "unit_mm_read_as_m"
    assert check_depth(stats, det, det, ok_ratio / 1000).problem == "unit_m_read_as_mm"
    shifted = check_depth(stats, det, det, ok_ratio * 2.6)       # hands read on the background
    assert shifted.problem == "misaligned_depth" and "align the depth" in shifted.message
    # a few off-depth detections (spurious hands) do not condemn the take
    some = ok_ratio.copy()
    some[:10, 0] = 3.0
    assert check_depth(stats, det, det, some).ok


def test_depth_coverage_counts_the_frames_and_detections_without_depth_at_the_hands():
    from demoforge.lib.ingest.depth_checks import DepthCheckConfig, coverage_warning, depth_coverage

    detected = np.zeros((20, 2), bool)
    detected[:, 0] = True                     # the left hand in every frame
    detected[10:, 1] = True                   # the right hand in the second half
    no_depth = np.zeros((20, 2), bool)
    no_depth[:4, 0] = True                    # 4 of the left hand's 20 detections
    no_depth[15:, 1] = True                   # 5 of the right hand's 10
    no_depth[5, 1] = True                     # not detected there: does not count
    c = depth_coverage(detected, no_depth)
    np.testing.assert_allclose(c.hand_missing, [0.2, 0.5])
    assert c.frame_missing == 9 / 20 and c.frames_with_hands == 20
    assert coverage_warning("t", c).startswith("take t: depth is missing at the hands in 45 % of the frames "
                                               "with a hand (left 20 %, right 50 % of each hand's detections)")
    assert coverage_warning("t", c, DepthCheckConfig(warn_missing_fraction=0.45)) == ""  # at the threshold: fine
    none = depth_coverage(np.zeros((5, 2), bool), np.ones((5, 2), bool))
    assert np.isnan(none.hand_missing).all() and np.isnan(none.frame_missing) and coverage_warning("t", none) == ""
