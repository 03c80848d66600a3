"""demoforge.lib.evaluation.keypoints: metric rows against hand-computed values, the thesis tables and figures."""

import math

import numpy as np
import pytest

from demoforge.lib.ingest.alignment import AlignmentConfig
from demoforge.lib.evaluation.keypoints import (
    APPENDIX_B_SECTIONS, BIG_OBJECTS, SMALL_OBJECTS, big_vs_small, common_K,
    evaluate_arctic_take, evaluate_synthetic_take, evaluate_take, format_markdown, gt_anchor_depth,
    per_object, plot_big_vs_small, plot_per_object_bars, plot_per_take_bars, project_per_frame,
    real_photo_rows, size_group,
)
from tests.support.keypoint_tables import appendix_b, table1, table2

K = np.array([[100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 1.0]])


def gt_hand(x0=0.0):
    """21 joints at z = 1 m, x from x0 to x0 + 0.2 m -> u spans 20 px with K; y in [0, 0.1]."""
    j = np.zeros((21, 3))
    j[:, 0] = x0 + np.linspace(0, 0.2, 21)
    j[:, 1] = np.linspace(0, 0.1, 21) ** 2 * 10      # not collinear (Procrustes needs 3D spread)
    j[:, 2] = 1.0 + 0.01 * np.sin(np.arange(21))
    return j


def two_hands(T=4):
    g = np.stack([gt_hand(-0.5), gt_hand(0.3)])          # left, right
    return np.broadcast_to(g, (T, 2, 21, 3)).copy()


def test_metrics_by_hand():
    T = 4
    G = two_hands(T)
    P = G.copy()
    P[:, :, :10, 0] += 0.005          # 0.5 px at z ~ 1
    P[:, :, 10:, 0] += 0.02           # 2 px
    # make z exactly 1 so the pixel errors are exact
    G[..., 2] = 1.0
    P[..., 2] = 1.0
    present = np.ones((T, 2), bool)
    present[3, 0] = False             # left missed in frame 3
    valid = np.ones((T, 2), bool)
    valid[2, 1] = False               # right GT invalid in frame 2
    rows = evaluate_take(P, G, None, K, present, valid, take="box_grab_01", obj="box")
    L, R = rows
    assert (L["hand"], R["hand"]) == ("left", "right")
    assert L["n_valid"] == 4 and L["n_eval"] == 3 and L["detection_rate"] == pytest.approx(0.75)
    assert R["n_valid"] == 3 and R["n_eval"] == 3 and R["detection_rate"] == 1.0
    for r in rows:
        assert r["mpjpe_m"] == pytest.approx((10 * 0.005 + 11 * 0.02) / 21)
        assert r["rr_mpjpe_m"] == pytest.approx(11 * 0.015 / 21)
        assert r["mpjpe_2d_px"] == pytest.approx((10 * 0.5 + 11 * 2.0) / 21)
        # box size 20 px: PCK@0.05 -> < 1 px: the 10 joints at 0.5 px; PCK@0.15 -> < 3 px: all
        assert r["pck05"] == pytest.approx(10 / 21)
        assert r["pck15"] == 1.0
        assert r["size_group"] == "big" and r["anchor_depth_source"] == "ground_truth"
        assert "ground-truth" in r["note"]
        assert math.isnan(r["mpjpe_2d_pred_px"])


def test_pa_mpjpe_zero_for_known_similarity():
    T = 3
    G = two_hands(T)
    c, s = np.cos(0.4), np.sin(0.4)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    P = 1.3 * G @ R.T + np.array([0.1, -0.05, 0.7])
    rows = evaluate_take(P, G, None, K, np.ones((T, 2), bool), np.ones((T, 2), bool))
    for r in rows:
        assert r["pa_mpjpe_m"] == pytest.approx(0.0, abs=1e-9)
        assert r["mpjpe_m"] > 0.5


@pytest.mark.parametrize("cfg", [None, "thesis", AlignmentConfig(surface_offset_m=0.0, scale_correction="none")])
def test_aligned_error_zero_for_depth_shift(cfg):
    """Prediction = GT shifted along z by a constant, with the detector's (correct) 2D: after the
    alignment with the GT anchor depth the error is 0."""
    T = 6
    G = two_hands(T)
    P = G + np.array([0.0, 0.0, 1.3])
    gt_px = project_per_frame(G, K)
    rows = evaluate_take(P, G, gt_px, K, np.ones((T, 2), bool), np.ones((T, 2), bool), pred_px=gt_px,
                         alignment_config=cfg)
    for r in rows:
        assert r["mpjpe_m"] == pytest.approx(1.3)
        assert r["mpjpe_aligned_m"] == pytest.approx(0.0, abs=1e-9)
        assert r["mpjpe_aligned_all_m"] == pytest.approx(0.0, abs=1e-9)
        assert r["mpjpe_2d_pred_px"] == pytest.approx(0.0, abs=1e-9)
        assert r["pck05_pred"] == 1.0 and r["pck05_aligned"] == 1.0


def test_gt_anchor_depth_follows_the_hand_the_prediction_lies_on():
    T = 2
    G = two_hands(T)
    G[:, 0, :, 2] = 0.5                # left GT at z 0.5, right at 1.0
    G[:, 1, :, 2] = 1.0
    P = G.copy()
    P[1] = G[1, ::-1]                  # frame 1: detector swapped the labels
    z = gt_anchor_depth(P, G, K, (0, 2))
    assert z[0].tolist() == [[0.5, 0.5], [1.0, 1.0]]
    assert z[1].tolist() == [[1.0, 1.0], [0.5, 0.5]]
    P[0, 1] = np.nan                   # no prediction -> NaN
    assert np.isnan(gt_anchor_depth(P, G, K, (0,))[0, 1]).all()


def test_common_K_remaps_pixels_exactly():
    T = 3
    Ks = np.stack([K + np.diag([5.0 * t, 5.0 * t, 0]) + np.array([[0, 0, t], [0, 0, 2 * t], [0, 0, 0]]) for t in range(T)])
    X = two_hands(T)
    px = project_per_frame(X, Ks)
    K0, px0 = common_K(Ks, px)
    np.testing.assert_allclose(K0, Ks[0])
    np.testing.assert_allclose(px0, project_per_frame(X, K0), atol=1e-9)


def test_per_frame_K_take_evaluates():
    T = 4
    Ks = np.stack([K * [[1 + 0.01 * t], [1 + 0.01 * t], [1]] for t in range(T)])
    G = two_hands(T)
    P = G + np.array([0.0, 0.0, 0.5])
    gpx = project_per_frame(G, Ks)
    rows = evaluate_take(P, G, gpx, Ks, np.ones((T, 2), bool), np.ones((T, 2), bool), pred_px=gpx)
    assert rows[0]["mpjpe_aligned_m"] == pytest.approx(0.0, abs=1e-9)


def test_evaluate_arctic_take_on_fixture(tmp_path):
    from demoforge.lib.evaluation.arctic import ArcticDataset
    from tests.support.arctic_fixture import build_arctic_tree

    root = build_arctic_tree(tmp_path / "a")
    tk = ArcticDataset(root).load("s01", "box_grab_01")
    P = tk.joints_cam + np.array([0.0, 0.0, 0.4])
    rows = evaluate_arctic_take(tk, P, pred_px=tk.joints_px)
    assert [r["hand"] for r in rows] == ["left", "right"]
    assert rows[0]["take"] == "box_grab_01" and rows[0]["object"] == "box" and rows[0]["subject"] == "s01"
    assert rows[0]["n_valid"] == 8 and rows[1]["n_valid"] == 9         # fixture's invalid frames
    for r in rows:
        assert r["mpjpe_m"] == pytest.approx(0.4)
        assert r["mpjpe_aligned_m"] == pytest.approx(0.0, abs=1e-9)
        assert r["mpjpe_2d_pred_px"] == pytest.approx(0.0, abs=1e-9)


# --------------------------------------------------------------------------- tables


def mk(take, hand, n, **m):
    base = dict(take=take, hand=hand, object=take.split("_")[0], size_group=size_group(take.split("_")[0]),
                n_eval=n, n_eval_aligned=n)
    base.update(m)
    return base


ROWS = [
    mk("box_grab_01", "left", 10, mpjpe_m=1.0, mpjpe_aligned_m=0.03, pa_mpjpe_m=0.04, pa_mpjpe_aligned_m=0.04,
       mpjpe_2d_px=30.0, pck05=0.5, pck15=1.0),
    mk("box_grab_01", "right", 10, mpjpe_m=1.2, mpjpe_aligned_m=0.05, pa_mpjpe_m=0.02, pa_mpjpe_aligned_m=0.02,
       mpjpe_2d_px=40.0, pck05=0.4, pck15=0.9),
    mk("phone_use_01", "left", 30, mpjpe_m=2.0, mpjpe_aligned_m=0.01, pa_mpjpe_m=0.02, pa_mpjpe_aligned_m=0.02,
       mpjpe_2d_px=10.0, pck05=0.9, pck15=1.0),
    mk("phone_use_01", "right", 30, mpjpe_m=1.6, mpjpe_aligned_m=0.01, pa_mpjpe_m=0.01, pa_mpjpe_aligned_m=0.01,
       mpjpe_2d_px=20.0, pck05=0.8, pck15=1.0),
    mk("scissors_use_02", "left", 0, mpjpe_m=float("nan"), mpjpe_aligned_m=float("nan"), pa_mpjpe_m=float("nan"),
       pa_mpjpe_aligned_m=float("nan"), mpjpe_2d_px=float("nan"), pck05=float("nan"), pck15=float("nan")),
]


def test_table1_frames_and_takes_weighting():
    t = table1(ROWS)
    assert [r["method"] for r in t] == ["Left Hand", "Left Hand (Aligned)", "Right Hand", "Right Hand (Aligned)"]
    assert t[0]["mpjpe_m"] == pytest.approx((1.0 * 10 + 2.0 * 30) / 40)
    assert t[0]["pa_mpjpe_m"] == pytest.approx((0.04 * 10 + 0.02 * 30) / 40)
    assert t[1]["mpjpe_m"] == pytest.approx((0.03 * 10 + 0.01 * 30) / 40)
    assert t[3]["mpjpe_m"] == pytest.approx((0.05 * 10 + 0.01 * 30) / 40)
    tt = table1(ROWS, weighting="takes")
    assert tt[0]["mpjpe_m"] == pytest.approx(1.5)          # NaN take ignored
    assert tt[2]["mpjpe_m"] == pytest.approx(1.4)


def test_table2():
    t = table2(ROWS, weighting="takes")
    assert [r["hand"] for r in t] == ["Left Hand", "Right Hand"]
    assert t[0]["mpjpe_2d_px"] == pytest.approx(20.0) and t[0]["pck05"] == pytest.approx(0.7)
    assert t[1]["pck15"] == pytest.approx(0.95)
    assert table2(ROWS)[1]["mpjpe_2d_px"] == pytest.approx((40 * 10 + 20 * 30) / 40)


def test_appendix_b_layout():
    a = appendix_b(ROWS)
    assert [r["take"] for r in a] == ["scissors_use_02", "box_grab_01", "phone_use_01"]   # the thesis's order
    box = a[1]
    assert box["mpjpe_left"] == 1.0 and box["mpjpe_left_aligned"] == 0.03
    assert box["mpjpe_right"] == 1.2 and box["pa-mpjpe_right_aligned"] == 0.02
    assert box["2D_mpjpe_r"] == 40.0 and box["2D_mpjpe_l"] == 30.0 and box["pck05_r"] == 0.4
    assert math.isnan(a[0]["mpjpe_right"])                  # scissors: no right row
    cols = [c for _, cs in APPENDIX_B_SECTIONS for c in cs]
    assert set(cols) <= set(box)
    md = format_markdown(a, APPENDIX_B_SECTIONS[0][1])
    assert md.splitlines()[0] == "| take | mpjpe_left | mpjpe_left_aligned | mpjpe_right | mpjpe_right_aligned |"
    assert "| box_grab_01 | 1.000 | 0.030 | 1.200 | 0.050 |" in md


def test_big_vs_small_and_per_object():
    assert BIG_OBJECTS == ("box", "capsulemachine", "espressomachine")
    assert SMALL_OBJECTS == ("ketchup", "phone", "scissors")
    bs = big_vs_small(ROWS, weighting="takes")
    assert [g["group"] for g in bs] == ["big", "small"]
    assert bs[0]["mpjpe_aligned_m"] == pytest.approx(0.04) and bs[0]["n_takes"] == 1
    assert bs[1]["mpjpe_aligned_m"] == pytest.approx(0.01) and bs[1]["n_takes"] == 2
    assert bs[1]["pa_mpjpe_m"] == pytest.approx(0.015)
    po = per_object(ROWS, weighting="takes")
    assert [p["object"] for p in po] == ["box", "phone", "scissors"]
    assert po[0]["pck05"] == pytest.approx(0.45) and po[0]["label"] == "box"


def test_png_writers(tmp_path):
    for f in (plot_per_take_bars(ROWS, "mpjpe_aligned_m", tmp_path / "take.png"),
              plot_per_object_bars(ROWS, ("mpjpe_aligned_m", "pa_mpjpe_m"), tmp_path / "fig19.png"),
              plot_per_object_bars(ROWS, ("pck05", "pck15"), tmp_path / "fig20a.png"),
              plot_big_vs_small(ROWS, tmp_path / "fig21a.png", "3d"),
              plot_big_vs_small(ROWS, tmp_path / "fig21b.png", "2d")):
        data = f.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000


def test_real_photo_rows_by_hand():
    from demoforge.lib.evaluation.real_photos import DatasetResult

    r = DatasetResult("panoptic", images=2, hands=3, detected=2, side_known=2, side_correct=1,
                      errors=[np.array([1.0, 3.0]), np.array([2.0])],
                      norm_errors=[np.array([0.01, 0.1]), np.array([0.3])], joints_all=6)
    rows = real_photo_rows([r])
    p, a = rows
    assert p["dataset"] == "panoptic" and a["dataset"] == "all"
    assert p["detection_rate"] == pytest.approx(2 / 3) and p["handedness_acc"] == 0.5
    assert p["mpjpe_2d_px"] == pytest.approx(2.0)
    assert p["pck05"] == pytest.approx(1 / 3) and p["pck15"] == pytest.approx(2 / 3)
    assert p["pck20"] == pytest.approx(2 / 3) and p["pck20_all"] == pytest.approx(2 / 6)


@pytest.mark.slow
def test_synthetic_take_rows(tmp_path):
    from demoforge.lib.synth.take import generate_take

    out = tmp_path / "t"
    generate_take("pouring", seed=3, mirror=False, out_dir=out, max_frames=20, video=False)
    rows = evaluate_synthetic_take(out)
    assert [r["hand"] for r in rows] == ["left", "right"]
    for r in rows:
        assert r["dataset"] == "synthetic" and r["detector"] == "simulated"
        assert r["anchor_depth_source"] == "depth"
        assert r["n_eval"] > 0  # both hands are in view in these 20 frames
        assert 0 <= r["pa_mpjpe_m"] <= r["mpjpe_m"]
        assert np.isfinite(r["mpjpe_aligned_m"])
    zero = evaluate_synthetic_take(out, anchor_depth_source="ground_truth", config="zero_noise")
    for r in zero:
        assert r["n_eval"] > 0
        assert r["mpjpe_m"] == pytest.approx(0.0, abs=1e-9)
        assert r["mpjpe_aligned_m"] == pytest.approx(0.0, abs=1e-6)


def test_evaluate_arctic_take_accepts_a_handtrack(tmp_path):
    from demoforge.lib.evaluation.arctic import ArcticDataset
    from demoforge.lib.perception.detectors import HandTrack
    from tests.support.arctic_fixture import build_arctic_tree

    tk = ArcticDataset(build_arctic_tree(tmp_path / "a")).load("s01", "box_grab_01")
    n = tk.n_frames
    present = np.ones((n, 2), bool)
    present[0, 1] = False
    P = np.where(present[..., None, None], tk.joints_cam, np.nan)
    tr = HandTrack(joints_cam=P, joints_px=np.where(present[..., None, None], tk.joints_px, np.nan),
                   confidence=present.astype(float), present=present, n_candidates=present.astype(np.int64),
                   detector="fake", detector_version="0")
    rows = evaluate_arctic_take(tk, tr)
    assert rows[1]["detector"] == "fake" and rows[1]["n_eval"] == 8 and rows[1]["detection_rate"] == pytest.approx(8 / 9)
    assert rows[0]["mpjpe_m"] == pytest.approx(0.0, abs=1e-12) and rows[0]["pck05"] == 1.0
