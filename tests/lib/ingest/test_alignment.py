"""Tests of demoforge.lib.ingest.alignment: robust depth read, depth alignment, swap repair, freeze and fill."""


import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from demoforge.lib.ingest.alignment import (
    AlignmentConfig, align_to_depth, backproject, fill_gaps, freeze_outliers, nan_median, project,
    read_depth_robust, repair_swaps,
)
from demoforge.lib.perception.hand_model import hand_joints
from tests.support.paths import CHECKOUT_SHARED_DATA

DEXCAP = CHECKOUT_SHARED_DATA / "rgbd" / "dexcap_frame_0"
DEXCAP_K = np.array([[898.2010498046875, 0, 657.4981079101562], [0, 897.86669921875, 364.30950927734375], [0, 0, 1]])
K = np.array([[570.0, 0, 319.5], [0, 570.0, 239.5], [0, 0, 1]])
H, W = 480, 640


def _trajectory(T, seed=0):
    """Two smooth hands (T, 2, 21, 3) in the camera frame, about 0.6 m away, 30 cm apart."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None]
    out = np.zeros((T, 2, 21, 3))
    # back of the hand towards the camera (hand-local z -> -camera z), fingers up (x -> -y), with a
    # small random tilt: no joint hides another one
    base = np.stack([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], axis=1)
    from demoforge.lib.geometry import quat_exp
    from demoforge.lib.geometry import quat_to_matrix
    R0 = quat_to_matrix(quat_exp(rng.normal(0, 0.1, (2, 3)))) @ base
    for h in range(2):
        Tw = np.tile(np.eye(4), (T, 1, 1))
        Tw[:, :3, :3] = R0[h]
        Tw[:, :3, 3] = np.array([-0.15 if h == 0 else 0.15, 0.05, 0.6]) \
            + 0.05 * np.sin(0.05 * t + h) * np.array([1.0, 0.5, 0.3])
        out[:, h] = hand_joints(Tw, np.full((T, 5), 0.3), "left" if h == 0 else "right")
    return out


def _depth_of_points(points, T, r=1, surface_offset=0.0):
    """A depth map per frame holding each joint's exact z in a (2r+1)^2 patch around its pixel
    (painted far to near: a z-buffer). With ``surface_offset`` the patch holds the depth of the skin
    seen in front of the joint: the point ``surface_offset`` m nearer along the joint's viewing ray."""
    d = np.zeros((T, H, W), np.float64)
    uv = np.rint(project(points, K)).astype(int)
    for t in range(T):
        flat = points[t].reshape(-1, 3)
        seen = flat[:, 2] - surface_offset * flat[:, 2] / np.linalg.norm(flat, axis=1)
        for k in np.argsort(-flat[:, 2]):
            u, v = uv[t].reshape(-1, 2)[k]
            if r <= u < W - r and r <= v < H - r:
                d[t, v - r:v + r + 1, u - r:u + r + 1] = seen[k]
    return d


# --------------------------------------------------------------------------- robust read


def test_nan_median_matches_numpy():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 9))
    x[rng.random(x.shape) < 0.3] = np.nan
    x[0] = np.nan
    med, n = nan_median(x)
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = np.nanmedian(x, axis=-1)
    np.testing.assert_allclose(med, ref, equal_nan=True)
    assert n[0] == 0 and np.isnan(med[0])


def test_read_depth_robust_synthetic_and_batch():
    d = np.full((2, 20, 30), 1.0, np.float32)
    d[0, 5:8, 5:8] = [[0, 2, 2], [0, 3, 0], [np.nan, 2, 4]]
    uv = np.array([[[6.0, 6.0], [np.nan, 1.0], [-10.0, -10.0]], [[6.0, 6.0], [29.0, 19.0], [0.0, 0.0]]])
    z, n = read_depth_robust(d, uv, window=3, min_valid=1)
    assert z[0, 0] == 2.0 and n[0, 0] == 5          # zeros and NaN skipped
    assert np.isnan(z[0, 1]) and n[0, 1] == 0       # NaN uv
    assert np.isnan(z[0, 2]) and n[0, 2] == 0       # outside
    assert z[1, 0] == 1.0 and n[1, 0] == 9
    assert z[1, 1] == 1.0 and n[1, 1] == 4          # corner: window clipped
    z2, _ = read_depth_robust(d, uv, window=3, min_valid=6)
    assert np.isnan(z2[0, 0])


@pytest.mark.skipif(not (DEXCAP / "depth_image.png").exists(), reason="../shared/data/rgbd/dexcap_frame_0 absent: the real RGB-D frame comes with "
                    "the shared data folder (../shared/data beside the checkout)")
def test_read_depth_robust_real_dexcap_frame():
    import cv2

    raw = cv2.imread(str(DEXCAP / "depth_image.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (720, 1280)
    depth = raw.astype(np.float64) / 1000.0
    zeros = np.argwhere(raw == 0)
    assert len(zeros) > 0
    rng = np.random.default_rng(0)
    # pixels next to holes and ordinary pixels
    picks = [tuple(zeros[i]) for i in rng.choice(len(zeros), 6, replace=False)] + [(360, 640), (100, 200), (700, 1270)]
    uv = np.array([[c, r] for r, c in picks], float)
    z, n = read_depth_robust(depth, uv, window=5, min_valid=1)
    for (r, c), zi, ni in zip(picks, z, n):
        win = raw[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3].astype(float)
        vals = win[win > 0] / 1000.0
        assert ni == vals.size
        if vals.size:
            assert zi == pytest.approx(np.median(vals))
            assert zi > 0
        else:
            assert np.isnan(zi)
    # round trip: back-project a pixel with its robust depth and reproject
    u, v = 640.3, 360.7
    zc, _ = read_depth_robust(depth, np.array([u, v]), 5)
    X = backproject(np.array([u, v]), zc, DEXCAP_K)
    assert X[2] == pytest.approx(zc)
    np.testing.assert_allclose(project(X, DEXCAP_K), [u, v], atol=1e-9)


# --------------------------------------------------------------------------- alignment


@settings(max_examples=10, deadline=None)
@given(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(0.2, 1.0), st.integers(0, 1000))
def test_exact_depth_pure_translation_recovers_gt(dx, dy, dz, seed):
    T = 4
    gt = _trajectory(T, seed)
    depth = _depth_of_points(gt, T)
    pred = gt + np.array([dx, dy, dz])
    px = project(gt, K)
    cfg = AlignmentConfig(surface_offset_m=0.0, scale_correction="none", anchors=(0, 1, 2, 5, 9),
                          window=1, min_valid=1, depth_outlier_m=None)
    res = align_to_depth(pred, depth, K, joints_px=px, config=cfg)
    # pixel rounding of the 2D look-up only changes the depth read, which is constant per patch;
    # back-projection uses the exact uv -> exact
    np.testing.assert_allclose(res.joints_cam, gt, atol=1e-6)
    np.testing.assert_allclose(res.translation, -np.broadcast_to([dx, dy, dz], (T, 2, 3)), atol=1e-6)
    assert not res.no_depth.any() and res.present.all()
    allowed = 1 << 0 | 1 << 1 | 1 << 2 | 1 << 5 | 1 << 9
    assert ((res.anchors_used & ~allowed) == 0).all()  # only anchors; overlapping patches rejected
    assert (res.n_anchors_valid == 5).all()


def test_no_depth_frames_filled_and_flagged_never_nan():
    T = 6
    gt = _trajectory(T, 3)
    depth = _depth_of_points(gt, T)
    depth[2] = 0.0  # no depth at all on frame 2
    pred = gt + 1.5 * gt[:, :, :1, :]  # the detector's error: the hand 2.5x too far along its root ray
    pred[4, 1] = np.nan  # right hand missed on frame 4
    px = project(gt, K)
    px[4, 1] = np.nan
    res = align_to_depth(pred, depth, K, joints_px=px,
                         config=AlignmentConfig(surface_offset_m=0.0, window=3))
    assert res.no_depth[2].all() and not res.no_depth[[0, 1, 3, 5]].any()
    assert np.isfinite(res.joints_cam).all()
    assert res.filled_missing[4, 1] and not res.detected[4, 1]
    assert np.abs(res.joints_cam[2] - gt[2]).max() < 0.01  # depth interpolated from neighbours
    # no depth in the whole take: raw prediction kept (translation 0), flagged, finite
    res0 = align_to_depth(pred, np.zeros_like(depth), K, joints_px=px)
    assert res0.no_depth[res0.detected].all()
    assert np.isfinite(res0.joints_cam).all()


def test_simulated_detector_alignment_reduces_error():
    from demoforge.lib.perception.simulated_detector import SimulatedDetectorConfig, simulate_detections
    from demoforge.lib.evaluation.metrics import mpjpe

    T = 60
    gt = _trajectory(T, 5)
    depth = _depth_of_points(gt, T)
    det = simulate_detections(gt, K, SimulatedDetectorConfig(swap_rate_hz=0.0, miss_rate_hz=0.0), seed=1)
    res = align_to_depth(det.joints_cam, depth, K, joints_px=det.joints_px,
                         config=AlignmentConfig(surface_offset_m=0.0))
    raw = mpjpe(det.joints_cam, gt)
    after = mpjpe(res.joints_cam, gt)
    assert raw > 0.5 and after < 0.03  # patchy synthetic depth; full takes: see the measurement script


# exact depth, one pixel per read, every option that is not under test off: the result is exact
EXACT = AlignmentConfig(surface_offset_m=0.0, scale_correction="none", anchors=(0, 1, 2, 5, 9), window=1,
                        min_valid=1, depth_outlier_m=None)


def _root_rays(gt):
    return gt[:, :, 0, :] / np.linalg.norm(gt[:, :, 0, :], axis=-1, keepdims=True)  # (T, 2, 3) unit


def test_ray_translation_moves_the_hand_along_its_root_ray_only():
    """`ray`: the detector's 2D is trusted, only its depth along the root's viewing ray is corrected;
    `free` also takes the lateral part of the error from the depth map."""
    T = 4
    gt = _trajectory(T, 2)
    depth = _depth_of_points(gt, T)
    lateral = np.array([0.02, -0.01, 0.0])
    pred = gt + 0.3 * _root_rays(gt)[:, :, None, :] + lateral   # too far along the ray, and 2 cm aside
    px = project(gt, K)
    free = align_to_depth(pred, depth, K, joints_px=px, config=EXACT)
    ray = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(translation="ray"))
    np.testing.assert_allclose(free.joints_cam, gt, atol=1e-6)
    np.testing.assert_allclose(ray.joints_cam, gt + lateral, atol=1e-6)  # the lateral error stays
    np.testing.assert_allclose(ray.translation, -0.3 * _root_rays(gt), atol=1e-6)


def test_frame_scale_follows_a_per_frame_size_error_and_take_scale_does_not():
    T = 8
    gt = _trajectory(T, 4)
    depth = _depth_of_points(gt, T)
    c = np.where(np.arange(T) < T // 2, 1.15, 0.9)                 # the detected hand's size error per frame
    root = gt[:, :, :1, :]
    pred = root + c[:, None, None, None] * (gt - root)
    px = project(gt, K)                                           # the 2D keypoints are right
    frame = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(scale_correction="frame"))
    take = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(scale_correction="take"))
    np.testing.assert_allclose(frame.scale, np.repeat(c[:, None], 2, 1), rtol=0.01)
    assert np.ptp(take.scale, axis=0).max() == 0.0                # one scale per hand for the whole take

    def size(x):  # wrist to middle-finger MCP, m
        return np.linalg.norm(x[:, :, 9] - x[:, :, 0], axis=-1)

    np.testing.assert_allclose(size(frame.joints_cam), size(gt), rtol=0.01)
    assert np.abs(size(take.joints_cam) / size(gt) - 1).max() > 0.08


def test_mean_combine_averages_the_anchors_and_median_ignores_one_off_reading():
    T = 3
    gt = _trajectory(T, 6)
    depth = _depth_of_points(gt, T)
    px = project(gt, K)
    u, v = np.rint(px[:, 0, 5]).astype(int).T                    # left hand, anchor 5 (index MCP)
    depth[np.arange(T), v, u] += 0.01                              # reads 1 cm deeper (inside anchor_outlier_m)
    pred = gt + np.array([0.0, 0.0, 0.2])
    med = align_to_depth(pred, depth, K, joints_px=px, config=EXACT)
    mean = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(combine="mean"))
    np.testing.assert_allclose(med.joints_cam, gt, atol=1e-6)
    ray5 = np.concatenate([px[:, 0, 5], np.ones((T, 1))], axis=1) @ np.linalg.inv(K).T  # z = 1 ray of anchor 5
    np.testing.assert_allclose(mean.translation[:, 0], -0.2 * np.array([0, 0, 1.0]) + 0.01 * ray5 / 5, atol=1e-6)
    np.testing.assert_allclose(mean.joints_cam[:, 1], gt[:, 1], atol=1e-6)  # the right hand's reads are exact


def test_temporal_depth_check_treats_an_occluded_frame_as_without_depth():
    """An object in front of both hands on one frame: every anchor reads 3 cm short. The temporal
    check flags the frame and takes its depth from the neighbours; without it the hands jump 3 cm
    (too little for the outlier freeze, 5 cm RMS)."""
    T = 12
    gt = _trajectory(T, 8)
    depth = _depth_of_points(gt, T)
    depth[6] = np.where(depth[6] > 0, depth[6] - 0.03, 0.0)
    pred = gt + 0.3 * _root_rays(gt)[:, :, None, :]  # the detector's error: along the root's viewing ray
    px = project(gt, K)
    on = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(depth_outlier_m=0.02))
    off = align_to_depth(pred, depth, K, joints_px=px, config=EXACT)
    assert on.depth_outlier[6].all() and on.depth_outlier.sum() == 2 and not off.depth_outlier.any()
    assert np.abs(on.joints_cam[6] - gt[6]).max() < 0.002        # interpolated from frames 5 and 7
    np.testing.assert_allclose(on.joints_cam[[5, 7]], gt[[5, 7]], atol=1e-6)
    assert np.abs(off.joints_cam[6, :, 0, 2] - gt[6, :, 0, 2]).min() > 0.025


def test_anchor_reading_an_occluder_is_dropped():
    """Two anchors of the left hand read an object 4 cm in front of the hand: they leave the vote
    (anchors_used) and the other anchors give the exact translation; with the check off they bias it."""
    T = 3
    gt = _trajectory(T, 9)
    depth = _depth_of_points(gt, T)
    px = project(gt, K)
    for a in (1, 2):
        u, v = np.rint(px[:, 0, a]).astype(int).T
        depth[np.arange(T), v, u] -= 0.04
    pred = gt + np.array([0.0, 0.0, 0.2])
    cfg = EXACT.with_(combine="mean")
    res = align_to_depth(pred, depth, K, joints_px=px, config=cfg)
    assert (res.anchors_used[:, 0] == (1 << 0 | 1 << 5 | 1 << 9)).all()
    assert (res.anchors_used[:, 1] == (1 << 0 | 1 << 1 | 1 << 2 | 1 << 5 | 1 << 9)).all()
    np.testing.assert_allclose(res.joints_cam, gt, atol=1e-6)
    kept = align_to_depth(pred, depth, K, joints_px=px, config=cfg.with_(anchor_outlier_m=np.inf))
    assert (kept.anchors_used[:, 0] == (1 << 0 | 1 << 1 | 1 << 2 | 1 << 5 | 1 << 9)).all()
    assert np.abs(kept.joints_cam[:, 0, :, 2] - gt[:, 0, :, 2]).min() > 0.01


@settings(max_examples=10, deadline=None)
@given(st.floats(0.005, 0.02), st.integers(0, 1000))
def test_surface_offset_puts_the_joint_behind_the_seen_skin(offset, seed):
    """The depth camera sees the skin, not the joint centre: with the skin `offset` m in front of each
    joint along its viewing ray, surface_offset_m = offset recovers the joints exactly, 0 leaves the
    hand too near by about the offset."""
    T = 3
    gt = _trajectory(T, seed)
    depth = _depth_of_points(gt, T, surface_offset=offset)
    pred = gt + np.array([0.01, 0.0, 0.25])
    px = project(gt, K)
    res = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(surface_offset_m=offset))
    np.testing.assert_allclose(res.joints_cam, gt, atol=1e-6)
    per_joint = np.full(21, offset)
    res21 = align_to_depth(pred, depth, K, joints_px=px, config=EXACT.with_(surface_offset_m=tuple(per_joint)))
    np.testing.assert_allclose(res21.joints_cam, gt, atol=1e-6)
    near = align_to_depth(pred, depth, K, joints_px=px, config=EXACT)
    dz = gt[..., 2] - near.joints_cam[..., 2]
    np.testing.assert_allclose(dz, offset * np.median(_root_rays(gt)[..., 2]), rtol=0.05)


# --------------------------------------------------------------------------- swaps, freeze, fill


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000))
def test_swap_repair_undoes_injected_swaps(seed):
    rng = np.random.default_rng(seed)
    T = 120
    gt = _trajectory(T, seed)
    swapped = np.zeros(T, bool)
    for _ in range(3):
        s = int(rng.integers(0, T - 6))
        swapped[s:s + int(rng.integers(1, 6))] = True
    pred = gt.copy()
    pred[swapped] = pred[swapped][:, ::-1]
    px = project(pred, K)
    depth = _depth_of_points(gt, T)
    res = align_to_depth(pred, depth, K, joints_px=px, config=AlignmentConfig(surface_offset_m=0.0, window=1, min_valid=1))
    np.testing.assert_array_equal(res.swap_frames, swapped)
    np.testing.assert_allclose(res.joints_cam, gt, atol=1e-6)
    # 2D centroids alone
    cen = project(pred, K).mean(axis=2)
    np.testing.assert_array_equal(repair_swaps(cen, np.ones((T, 2), bool)), swapped)


def test_swap_repair_with_single_hand_frames_and_first_frame_swapped():
    T = 40
    gt = _trajectory(T, 11)
    pred = gt.copy()
    sw = np.zeros(T, bool)
    sw[0:3] = True   # take starts swapped
    sw[20:23] = True
    pred[sw] = pred[sw][:, ::-1]
    present = np.ones((T, 2), bool)
    present[21, 0] = False  # one hand missed during a swap
    cen = project(pred, K).mean(axis=2)
    cen[~present] = np.nan
    np.testing.assert_array_equal(repair_swaps(cen, present), sw)


def test_freeze_thesis_rule():
    T = 10
    x = np.zeros((T, 2, 21, 3))
    x[:, :, :, 0] = np.arange(T)[:, None, None] * 0.001      # slow motion
    x[4:6, 0] += 0.5                                          # two-frame jump on the left hand
    present = np.ones((T, 2), bool)
    fr = freeze_outliers(x, present, threshold=2.5e-3, max_freeze=15)
    assert fr[:, 0].tolist() == [False] * 4 + [True, True] + [False] * 4
    assert not fr[:, 1].any()
    # a permanent jump: frozen for max_freeze frames, then accepted
    y = np.zeros((T, 2, 21, 3))
    y[3:, 1] += 1.0
    fr = freeze_outliers(y, present, threshold=2.5e-3, max_freeze=2)
    assert fr[:, 1].tolist() == [False] * 3 + [True, True] + [False] * 5


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["hold", "interpolate"]))
def test_freeze_and_fill_never_nan(seed, mode):
    rng = np.random.default_rng(seed)
    T = int(rng.integers(2, 40))
    x = np.cumsum(rng.normal(0, 0.03, (T, 2, 21, 3)), axis=0)
    x[rng.random(T) < 0.1] += rng.normal(0, 1.0, 3)
    present = rng.random((T, 2)) < 0.7
    present[rng.integers(0, T), :] = True  # each hand detected at least once
    x = np.where(present[..., None, None], x, np.nan)
    fr = freeze_outliers(x, present, 2.5e-3, int(rng.integers(0, 10)))
    assert not (fr & ~present).any()
    good = present & ~fr
    assert good.any(axis=0).all()  # the first detection is always accepted
    out = fill_gaps(x, good, mode)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[good], x[good])


def test_fill_gaps_interpolates_and_holds():
    x = np.arange(6, dtype=float)[:, None, None].repeat(2, 1)
    good = np.array([[False, True], [True, True], [False, True], [False, False], [True, True], [False, True]])
    out = fill_gaps(x, good, "interpolate")[:, 0, 0]
    np.testing.assert_allclose(out, [1, 1, 2, 3, 4, 4])
    out = fill_gaps(x, good, "hold")[:, 0, 0]
    np.testing.assert_allclose(out, [1, 1, 1, 1, 4, 4])


def test_config_validation_and_thesis_preset():
    with pytest.raises(ValueError):
        AlignmentConfig(window=4)
    with pytest.raises(ValueError):
        AlignmentConfig(fill="spline")
    th = AlignmentConfig.thesis()
    assert th.anchors == (2,) and not th.repair_swaps and th.scale_correction == "none"


def test_nan_quantile_matches_numpy():
    from demoforge.lib.ingest.alignment import nan_quantile
    import warnings

    rng = np.random.default_rng(3)
    x = rng.normal(size=(40, 7))
    x[rng.random(x.shape) < 0.3] = np.nan
    for q in (0.0, 0.5, 0.8, 1.0):
        v, _ = nan_quantile(x, q)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = np.nanquantile(x, q, axis=-1)
        np.testing.assert_allclose(v, ref, equal_nan=True)
