"""The "hamer" detector backend (demoforge.lib.perception.hamer.backend): box sources, tracking, model cache, errors."""

from __future__ import annotations

import numpy as np
import pytest

from demoforge.lib.perception.detectors import (
    DetectorError, get_detector, register_detector, select_best_hands,
)
from demoforge.lib.perception.hamer.backend import HamerDetector, get_predictor
from demoforge.lib.perception.hamer.camera import box_from_keypoints
from demoforge.lib.perception.hamer.checkpoint import save_random_checkpoint
from demoforge.lib.perception.hamer.model import HamerConfig
from demoforge.lib.perception.hamer.synthetic import synthetic_mano, write_synthetic_mano
from demoforge.lib import SHARED_DATA
from tests.support.mediapipe_model import require_mediapipe_model

TINY = HamerConfig.tiny()
K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
PHOTO = SHARED_DATA / "real_hands" / "onehand10k" / "9.jpg"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("hamer_backend")
    save_random_checkpoint(d / "hamer.ckpt", TINY, seed=2)
    write_synthetic_mano(d / "MANO_RIGHT.pkl", synthetic_mano()[0])
    return dict(checkpoint=str(d / "hamer.ckpt"), mano_model=str(d / "MANO_RIGHT.pkl"), config=TINY, device="cpu")


def frames(n=3, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, 240, 320, 3), dtype=np.uint8)


def test_previous_box_source_tracks_each_hand_from_its_last_keypoints(files):
    det = HamerDetector(**files, box_source="previous", fallback="none", min_track_confidence=0.0,
                        initial_boxes={"left": (60, 80, 120, 160), "right": (190, 70, 250, 150)})
    out = det.detect(frames(3), K, [0, 1, 2])
    assert [sorted(c.handedness for c in f) for f in out] == [["left", "right"]] * 3
    for t in range(3):
        for c in out[t]:
            assert c.joints_cam.shape == (21, 3) and c.joints_px.shape == (21, 2)
            assert 0.0 <= c.confidence <= 1.0 and np.all(c.joints_cam[:, 2] > 0)
    first = {c.handedness: c for c in out[0]}
    second = {c.handedness: c for c in out[1]}
    np.testing.assert_array_equal(first["left"].extra["box"], [60, 80, 120, 160])
    for side in ("left", "right"):  # frame 1's box is frame 0's keypoint box
        np.testing.assert_allclose(second[side].extra["box"], box_from_keypoints(first[side].joints_px))
        assert second[side].extra["box_source"] == "previous"
    track = select_best_hands(out, 3, detector=det.name, detector_version=det.version)
    assert track.present.all() and track.joints_cam.shape == (3, 2, 21, 3)
    # a new take starts again from the initial boxes
    det.reset()
    again = det.detect(frames(1), K, [0])
    np.testing.assert_array_equal({c.handedness: c for c in again[0]}["right"].extra["box"], [190, 70, 250, 150])


def test_a_lost_track_is_dropped_and_without_fallback_stays_lost(files):
    det = HamerDetector(**files, fallback="none", min_track_confidence=1.01, initial_boxes={"right": (190, 70, 250, 150)})
    out = det.detect(frames(2), K, [0, 1])
    assert [len(f) for f in out] == [1, 0]


def test_model_is_loaded_once_and_shared(files):
    a = HamerDetector(**files, fallback="none")
    b = HamerDetector(**files, box_source="previous", fallback="none")
    assert a.predictor is b.predictor
    assert get_predictor(files["checkpoint"], files["mano_model"], "cpu", TINY, batch_size=16, rescale_factor=2.0,
                         translation="crop_camera", amp=False) is a.predictor


def test_registry_and_clear_errors(files, tmp_path):
    register_detector("hamer", "demoforge.lib.perception.hamer.backend:HamerDetector")
    det = get_detector("hamer", **files, fallback="none", initial_boxes={"left": (10, 10, 80, 90)})
    assert det.name == "hamer" and "previous" in det.version
    with pytest.raises(DetectorError, match="--hamer-checkpoint"):
        HamerDetector(checkpoint=tmp_path / "missing.ckpt", mano_model=files["mano_model"])
    with pytest.raises(DetectorError, match="--mano-model"):
        HamerDetector(checkpoint=files["checkpoint"], mano_model=tmp_path / "MANO_RIGHT.pkl")
    with pytest.raises(ValueError, match="box_source"):
        HamerDetector(**files, box_source="vitpose")


def _photo():
    import cv2

    if not PHOTO.is_file():
        pytest.skip(f"{PHOTO} not present: the real hand photos come with the shared data folder "
                    "(../shared/data beside the checkout)")
    require_mediapipe_model()
    rgb = cv2.cvtColor(cv2.imread(str(PHOTO)), cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    return rgb, np.array([[500.0, 0, w / 2], [0, 500.0, h / 2], [0, 0, 1]])


def test_mediapipe_boxes(files):
    rgb, Kp = _photo()
    det = HamerDetector(**files, box_source="mediapipe")  # a DetectorError here is a failure, not a skip
    (cands,) = det.detect(rgb[None], Kp, [0])
    mp = det._mediapipe().detect_image(rgb, Kp, 0)
    assert len(cands) == len(mp) >= 1
    for c, m in zip(cands, mp):
        assert c.extra["box_source"] == "mediapipe" and c.handedness == m.handedness
        np.testing.assert_allclose(c.extra["box"], box_from_keypoints(m.joints_px))
        assert c.confidence <= m.confidence + 1e-12
    # "previous" without a track falls back to MediaPipe for that hand
    prev = HamerDetector(**files, box_source="previous", fallback="mediapipe")
    (first,) = prev.detect(rgb[None], Kp, [0])
    assert {c.extra["box_source"] for c in first} == {"mediapipe"}
    det.close()
    prev.close()


def test_detect_take_on_a_short_synthetic_take(files, tmp_path):
    from demoforge.lib.takes import open_take
    from demoforge.lib.synth.take import generate_take

    generate_take("pouring", 0, False, tmp_path / "take", video=False, max_frames=4)
    take = open_take(tmp_path / "take")
    h, w = take.camera.height, take.camera.width
    det = HamerDetector(**files, fallback="none", min_track_confidence=0.0,
                        initial_boxes={"left": (w * 0.2, h * 0.4, w * 0.35, h * 0.6),
                                       "right": (w * 0.6, h * 0.4, w * 0.75, h * 0.6)})
    track = det.detect_take(take, batch_size=2)
    assert track.n_frames == take.n_frames == 4 and track.detector == "hamer"
    assert track.present.all() and np.isfinite(track.joints_cam).all()
    # the take's own intrinsics place the hands: the wrist projects near the network's 2D wrist
    from demoforge.lib.geometry import project_points

    uv = project_points(track.joints_cam[:, :, 0], take.camera.K)
    assert np.all(np.abs(uv - track.joints_px[:, :, 0]) < 0.1 * w)
