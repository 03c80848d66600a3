"""demoforge.lib.perception.detectors: interface, best-hand selection, simulated and precomputed backends, registry."""

import json
import shutil

import numpy as np
import pytest

from demoforge.lib.perception.detectors import (
    DetectorError, HandCandidate, HandDetector, HandTrack, available_detectors, fit_translation_to_2d,
    get_detector, project_points, register_detector, select_best_hands,
)
from demoforge.lib.perception.detectors.precomputed import (
    PrecomputedDetector, load_predictions, write_predictions,
)
from demoforge.lib.perception.detectors.simulated import SimulatedDetector
from demoforge.lib.takes import open_take

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])


def _hand(z=0.6, dx=0.0, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(0, 0.03, (21, 3)) + [dx, 0, z]


def _cand(side, conf, dx=0.0):
    j = _hand(dx=dx)
    return HandCandidate(side, conf, project_points(j, K), j)


@pytest.fixture(scope="module")
def synth_take(tmp_path_factory):
    from demoforge.lib.synth.take import generate_take

    out = tmp_path_factory.mktemp("take") / "t"
    generate_take("pouring", seed=3, mirror=False, out_dir=out, max_frames=60, video=False)
    return out


def test_select_best_hands_picks_max_confidence_per_side():
    frames = [
        [_cand("left", 0.3, 0.1), _cand("left", 0.9, 0.2), _cand("right", 0.5, 0.3), _cand("right", 0.4, 0.4)],
        [],                                   # no hands
        [_cand("right", 0.7, 0.5)],           # one hand
    ]
    tr = select_best_hands(frames, 4, detector="x")
    assert tr.joints_cam.shape == (4, 2, 21, 3) and tr.joints_px.shape == (4, 2, 21, 2)
    np.testing.assert_array_equal(tr.present, [[True, True], [False, False], [False, True], [False, False]])
    np.testing.assert_allclose(tr.confidence, [[0.9, 0.5], [0, 0], [0, 0.7], [0, 0]])
    np.testing.assert_allclose(tr.joints_cam[0, 0], frames[0][1].joints_cam)
    np.testing.assert_allclose(tr.joints_cam[0, 1], frames[0][2].joints_cam)
    assert np.isnan(tr.joints_cam[1]).all() and np.isnan(tr.joints_px[2, 0]).all()
    np.testing.assert_array_equal(tr.n_candidates, [[2, 2], [0, 0], [0, 1], [0, 0]])
    # mapping and explicit frame indices give the same
    tr2 = select_best_hands({0: frames[0], 2: frames[2]}, 4)
    tr3 = select_best_hands([frames[0], frames[2]], 4, frame_indices=[0, 2])
    for t in (tr2, tr3):
        np.testing.assert_array_equal(t.present, tr.present)
        np.testing.assert_allclose(np.nan_to_num(t.joints_cam), np.nan_to_num(tr.joints_cam))
    assert select_best_hands([], 0).joints_cam.shape == (0, 2, 21, 3)


def test_hand_candidate_validation():
    with pytest.raises(ValueError, match="handedness"):
        HandCandidate("both", 0.5, np.zeros((21, 2)), np.zeros((21, 3)))
    with pytest.raises(ValueError, match="confidence"):
        HandCandidate("left", 1.5, np.zeros((21, 2)), np.zeros((21, 3)))


def test_fit_translation_recovers_exact_translation():
    rel = _hand(z=0.0, seed=4)
    t = np.array([0.05, -0.1, 0.7])
    est = fit_translation_to_2d(rel, project_points(rel + t, K), K)
    np.testing.assert_allclose(est, t, atol=1e-9)


def test_registry(monkeypatch):
    assert {"mediapipe", "simulated", "precomputed"} <= set(available_detectors())
    with pytest.raises(ValueError, match="mediapipe, precomputed, simulated"):
        get_detector("hamer_torch")

    class Dummy(HandDetector):
        name, version = "dummy", "0"

        def detect(self, rgb_batch, K, frame_indices):
            return [[] for _ in frame_indices]

    from demoforge.lib.perception.detectors import DETECTORS

    monkeypatch.setattr(DETECTORS, "_entries", dict(DETECTORS._entries))  # the registration ends with the test
    register_detector("dummy", Dummy)
    d = get_detector("dummy")
    assert d.detect(np.zeros((2, 4, 4, 3), np.uint8), K, [0, 1]) == [[], []]
    assert isinstance(get_detector("simulated"), SimulatedDetector)


def test_simulated_backend_on_synthetic_take(synth_take):
    take = open_take(synth_take)
    det = get_detector("simulated", config="zero_noise")
    tr = det.detect_take(take)
    assert isinstance(tr, HandTrack) and tr.detector == "simulated" and tr.n_frames == 60
    from demoforge.lib.perception.detectors.simulated import load_gt_hand_joints

    gt = load_gt_hand_joints(synth_take, 60)
    np.testing.assert_array_equal(tr.present, np.isfinite(gt).all(axis=(2, 3)))
    np.testing.assert_allclose(tr.joints_cam[tr.present], gt[tr.present], atol=1e-12)
    # per-batch interface returns slices of the same simulation (images are not used)
    cands = det.detect(None, take.camera.K, [0, 5])
    assert [c.handedness for c in cands[0]] == [s for s, p in zip(("left", "right"), tr.present[0]) if p]
    # the generic batched path (decoding frames) gives the same track
    tr_b = HandDetector.detect_take(det, take, batch_size=32)
    np.testing.assert_array_equal(tr_b.present, tr.present)


def test_simulated_backend_swaps_and_misses(synth_take):
    take = open_take(synth_take)
    base = SimulatedDetector(take, swap_rate_hz=0.0, miss_rate_hz=0.0, seed=1).detect_take()
    sw = SimulatedDetector(take, swap_rate_hz=3.0, miss_rate_hz=0.0, seed=1)
    tr = sw.detect_take()
    swapped = tr.extra["injected_swap"]
    assert swapped.any() and not swapped.all()
    # on swapped frames the slot labelled left holds the right hand's prediction
    both = swapped & base.present.all(axis=1)
    np.testing.assert_allclose(tr.joints_cam[both, 0], base.joints_cam[both, 1])
    cands = sw.detect(None, take.camera.K, np.nonzero(both)[0][:1])
    left = [c for c in cands[0] if c.handedness == "left"][0]
    np.testing.assert_allclose(left.joints_cam, base.joints_cam[np.nonzero(both)[0][0], 1])
    miss = SimulatedDetector(take, miss_rate_hz=3.0, swap_rate_hz=0.0, seed=1).detect_take()
    assert miss.extra["missed"].any()
    assert not miss.present[miss.extra["missed"]].any()
    assert np.isnan(miss.joints_cam[~miss.present]).all() and (miss.confidence[~miss.present] == 0).all()


def test_simulated_refuses_take_without_ground_truth(synth_take, tmp_path):
    dst = tmp_path / "real_like"
    shutil.copytree(synth_take, dst)
    shutil.rmtree(dst / "ground_truth")
    with pytest.raises(DetectorError, match="only runs on synthetic takes"):
        SimulatedDetector(open_take(dst))
    with pytest.raises(DetectorError, match="no take"):
        SimulatedDetector().detect(None, K, [0])


def _track(n=6, seed=0):
    rng = np.random.default_rng(seed)
    cands = {}
    for t in range(n):
        lst = []
        if t % 3 != 1:
            lst.append(_cand("left", float(rng.uniform(0.5, 1)), dx=-0.1 + 0.01 * t))
        if t % 2 == 0:
            lst.append(_cand("right", float(rng.uniform(0.5, 1)), dx=0.1))
            lst.append(_cand("right", 0.1, dx=0.3))          # a weaker duplicate
        cands[t] = lst
    return cands


@pytest.mark.parametrize("ext", ["parquet", "npz"])
def test_precomputed_roundtrip_rows(tmp_path, ext):
    cands = _track()
    p = write_predictions(tmp_path / f"pred.{ext}", cands)
    back = load_predictions(p, K=K)
    assert sorted(back) == sorted(k for k, v in cands.items() if v)
    ref = select_best_hands(cands, 6)
    det = get_detector("precomputed", path=p, K=K)
    got = select_best_hands(det.detect(None, K, range(6)), 6)
    np.testing.assert_array_equal(got.present, ref.present)
    np.testing.assert_allclose(np.nan_to_num(got.joints_cam), np.nan_to_num(ref.joints_cam))
    np.testing.assert_allclose(got.confidence, ref.confidence)
    np.testing.assert_array_equal(got.n_candidates, ref.n_candidates)


def test_precomputed_parquet_minimal_columns_projects_with_K(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    j = _hand()
    pq.write_table(pa.table({"frame": [0, 2], "hand": [1, 0],
                             "joints_cam": [j.reshape(-1).tolist(), j.reshape(-1).tolist()]}), tmp_path / "m.parquet")
    got = load_predictions(tmp_path / "m.parquet", K=K)
    assert got[0][0].handedness == "right" and got[0][0].confidence == 1.0
    np.testing.assert_allclose(got[2][0].joints_px, project_points(j, K))
    pq.write_table(pa.table({"frame": [0], "joints_cam": [j.reshape(-1).tolist()]}), tmp_path / "bad.parquet")
    with pytest.raises(DetectorError, match=r"missing column\(s\) \['hand'\]"):
        load_predictions(tmp_path / "bad.parquet", K=K)


def test_precomputed_npz_track_layout(tmp_path):
    ref = select_best_hands(_track(), 6)
    np.savez(tmp_path / "track.npz", joints_cam=ref.joints_cam, confidence=ref.confidence)
    got = select_best_hands(load_predictions(tmp_path / "track.npz", K=K), 6)
    np.testing.assert_array_equal(got.present, ref.present)
    np.testing.assert_allclose(np.nan_to_num(got.joints_px), np.nan_to_num(ref.joints_px))


def test_precomputed_thesis_json_roundtrip(synth_take, tmp_path):
    take = open_take(synth_take)
    names = [f"{i:06d}.png" for i in range(take.n_frames)]
    rng = np.random.default_rng(1)
    doc, truth = {}, {}
    for t in (0, 3, 4):
        entry = {"left": {}, "right": {}}
        for side in ("left", "right"):
            if t == 4 and side == "left":
                continue
            rel = rng.normal(0, 0.03, (21, 3))
            tr = np.array([rng.uniform(-0.1, 0.1), 0.0, 0.7])
            px = project_points(rel + tr, take.camera.K)
            entry[side] = {"3d_keypoints": rel.tolist(), "translation": tr.tolist(), "2d_keypoints": px.tolist(),
                           "focal_length": 525.0}
            truth[(t, side)] = rel + tr
        doc[names[t]] = entry
    p = tmp_path / "keypoint_all_take1.json"
    p.write_text(json.dumps(doc))
    det = PrecomputedDetector(p, take=take, name="hamer")
    tr = det.detect_take(take)
    assert tr.detector == "hamer" and tr.n_frames == take.n_frames
    assert tr.present.sum() == 5 and not tr.present[4, 0] and tr.present[4, 1]
    for (t, side), j in truth.items():
        np.testing.assert_allclose(tr.joints_cam[t, ("left", "right").index(side)], j)
    assert tr.confidence[tr.present].min() == 1.0
    # reproject_2d uses the take's K (same here, since the file was made with it)
    tr2 = PrecomputedDetector(p, take=take, reproject_2d=True).detect_take(take)
    np.testing.assert_allclose(np.nan_to_num(tr2.joints_px), np.nan_to_num(tr.joints_px), atol=1e-9)
    doc["999999.png"] = doc[names[0]]
    p.write_text(json.dumps(doc))
    with pytest.raises(DetectorError, match="wrong file for this take"):
        PrecomputedDetector(p).detect_take(take)


def test_precomputed_errors(tmp_path):
    with pytest.raises(DetectorError, match="does not exist"):
        PrecomputedDetector(tmp_path / "nope.parquet")
    (tmp_path / "x.csv").write_text("a")
    with pytest.raises(DetectorError, match="unsupported"):
        PrecomputedDetector(tmp_path / "x.csv")


def test_select_best_hands_property():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    cand = st.tuples(st.sampled_from(["left", "right"]), st.floats(0, 1), st.integers(0, 1000))

    @settings(max_examples=60, deadline=None)
    @given(st.lists(st.lists(cand, max_size=5), max_size=6))
    def check(frames):
        cands = [[HandCandidate(s, c, np.full((21, 2), k, float), np.full((21, 3), k, float)) for s, c, k in f]
                 for f in frames]
        tr = select_best_hands(cands, len(frames))
        for t, f in enumerate(frames):
            for h, side in enumerate(("left", "right")):
                mine = [(c, k) for s, c, k in f if s == side]
                assert tr.present[t, h] == bool(mine)
                assert tr.n_candidates[t, h] == len(mine)
                if mine:
                    best = max(mine, key=lambda x: x[0])       # first of equal maxima
                    assert tr.confidence[t, h] == best[0]
                    assert tr.joints_cam[t, h, 0, 0] == best[1]
                else:
                    assert np.isnan(tr.joints_cam[t, h]).all() and tr.confidence[t, h] == 0

    check()
