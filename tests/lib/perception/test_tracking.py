"""The temporal hand tracker (demoforge.lib.perception.tracking) on synthetic detection sequences with injected
swaps, drop-outs, spurious single-frame detections, duplicates and detections off their depth."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from demoforge.lib.geometry import backproject
from demoforge.lib.perception.tracking import (
    TrackerConfig, bounded_fill_mask, depth_size_ratio, hand_size_px, hand_trust, track_hands,
)

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
# a flat 21-point "hand" template, metres, about 18 cm across (wrist at the origin)
_ANG = np.linspace(-0.6, 0.6, 5)
TEMPLATE = np.concatenate([[[0.0, 0.0, 0.0]]] + [
    np.stack([np.sin(a) * r, -np.cos(a) * r, 0.0 * r], -1)[None] for a in _ANG for r in (0.05, 0.08, 0.11, 0.14)
]).reshape(21, 3)


def _sequence(T=200, seed=0, z=0.6):
    """Two hands moving smoothly: joints_px (T, 2, 21, 2), joints_cam (T, 2, 21, 3), anchor depth (T, 2, 7)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None]
    centre = np.stack([np.stack([220 + 40 * np.sin(t / 20 + h), 260 + 30 * np.cos(t / 25 + h)], -1)
                       for h in (0, 1)], axis=1)[:, :, 0]                      # (T, 2, 2)
    centre[:, 1, 0] += 200                                                      # right hand to the right
    wrist = backproject(centre, np.full(centre.shape[:-1], z), K)               # (T, 2, 3)
    cam = wrist[:, :, None, :] + TEMPLATE[None, None]
    cam += rng.normal(0, 0.002, cam.shape)
    px = cam[..., :2] / cam[..., 2:3] * K[[0, 1], [0, 1]] + K[:2, 2]
    depth = np.full((T, 2, 7), z)
    return px, cam, depth


def _track(px, cam, depth, present, conf=None, **cfg):
    return track_hands(px, present, conf, joints_cam=cam, anchor_depth=depth, K=K, config=TrackerConfig(**cfg))


def test_clean_two_hand_sequence_is_two_trusted_tracks():
    px, cam, depth = _sequence()
    present = np.ones((200, 2), bool)
    r = _track(px, cam, depth, present)
    assert r.accepted.all() and not r.swapped.any() and (r.rejected == 0).all()
    assert (r.track_id == 0).all()
    np.testing.assert_allclose(r.depth_ratio, 1.0, atol=0.05)   # on its depth at the size it shows
    trusted, reasons = hand_trust(r.accepted, r.detected, r.accepted)
    assert trusted.all() and reasons == ["", ""]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_injected_swaps_are_repaired(seed):
    px, cam, depth = _sequence(seed=seed)
    rng = np.random.default_rng(seed)
    swap = np.zeros(200, bool)
    for s in rng.choice(np.arange(10, 190), 5, replace=False):
        swap[s:s + rng.integers(1, 5)] = True
    px_in, cam_in = px.copy(), cam.copy()
    px_in[swap] = px[swap][:, ::-1]
    cam_in[swap] = cam[swap][:, ::-1]
    r = _track(px_in, cam_in, depth, np.ones((200, 2), bool))
    np.testing.assert_array_equal(r.swapped, swap)
    assert r.accepted.all()


def test_dropouts_are_bounded_gaps_and_a_long_one_splits_the_track():
    px, cam, depth = _sequence()
    present = np.ones((200, 2), bool)
    present[50:54, 0] = False          # short drop-out: inside the track
    present[100:130, 0] = False        # 30 frames: longer than max_gap_frames = 15
    r = _track(px, cam, depth, present)
    assert r.accepted[:, 0].sum() == present[:, 0].sum()
    assert r.track_id[51, 0] == 0 and r.track_id[110, 0] == -1 and r.track_id[150, 0] == 1
    fill = bounded_fill_mask(r.accepted, 15)
    assert fill[50:54, 0].all()                       # filled (and flagged later by the alignment)
    assert not fill[100:130, 0].any()                 # never bridged
    assert fill[:, 1].all()


def test_spurious_single_frame_detections_never_make_a_hand():
    """A take with one (right) hand: the detector reports a left hand in ~12 % of the frames, at random
    places, and sometimes calls the right hand 'left'. No left trajectory may come out of it."""
    px, cam, depth = _sequence(T=300, seed=4)
    rng = np.random.default_rng(4)
    present = np.zeros((300, 2), bool)
    present[:, 1] = True
    spurious = rng.random(300) < 0.12
    shift = rng.uniform(-250, 250, (300, 2))
    px[:, 0] = px[:, 1] + shift[:, None, :]           # a hand-shaped blob somewhere else
    cam[:, 0] = cam[:, 1]
    present[:, 0] = spurious
    flip = ~spurious & (rng.random(300) < 0.05)      # handedness flips of the real hand
    px[flip, 0], cam[flip, 0] = px[flip, 1], cam[flip, 1]
    present[flip] = [True, False]
    r = _track(px, cam, depth, present)
    assert not r.accepted[:, 0].any() and (r.track_id[:, 0] == -1).all()
    assert r.accepted[:, 1].sum() == 300              # flips went back to the right hand
    assert r.swapped[flip].all()
    assert (r.reason()[spurious & ~flip, 0] != "").all()
    trusted, reasons = hand_trust(bounded_fill_mask(r.accepted, 15), r.detected, r.accepted)
    assert list(trusted) == [False, True] and "isolated" in reasons[0]


def _one_hand(T=300, speed=1.0, seed=0):
    """One real hand moving fast across the image (up to ``speed`` * 10 px a frame), in both slots: the
    caller chooses which label the detector gives it per frame."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)
    centre = np.stack([320 + 150 * np.sin(speed * t / 15), 250 + 60 * np.cos(speed * t / 20)], -1)
    wrist = backproject(centre, np.full(T, 0.6), K)
    cam = wrist[:, None, :] + TEMPLATE[None]
    cam += rng.normal(0, 0.002, cam.shape)
    px = cam[..., :2] / cam[..., 2:3] * K[[0, 1], [0, 1]] + K[:2, 2]
    return np.stack([px, px], 1), np.stack([cam, cam], 1), np.full((T, 2, 7), 0.6)


def _label(T, bursts, gaps=()):
    """present (T, 2): the right label, except in ``bursts`` (the left label) and ``gaps`` (no detection)."""
    present = np.zeros((T, 2), bool)
    present[:, 1] = True
    for a, b in bursts:
        present[a:b] = [True, False]
    for a, b in gaps:
        present[a:b] = False
    return present


def test_one_hand_whose_label_flips_in_bursts_stays_one_hand():
    """MediaPipe's handedness flips on one real hand in bursts, often as it finds the hand again after
    losing it (the last position is then forgotten, and the hand moved meanwhile): every burst is long
    enough to be born as a track. Never seen beside the other, at the same place: one hand."""
    px, cam, depth = _one_hand()
    bursts, gaps = [(40, 70), (120, 136), (200, 262)], [(100, 120), (180, 200)]
    present = _label(300, bursts, gaps)
    r = _track(px, cam, depth, present)
    seen = present.any(axis=1)
    assert not r.accepted[:, 0].any() and (r.track_id[:, 0] == -1).all()
    np.testing.assert_array_equal(r.accepted[:, 1], seen)            # every detection is the one hand's
    for a, b in bursts:
        assert r.swapped[a:b].all() and (r.source_slot[a:b, 1] == 0).all()
    trusted, reasons = hand_trust(bounded_fill_mask(r.accepted, 15), r.detected, r.accepted)
    assert list(trusted) == [False, True] and reasons[0] == "never detected"
    # the label that holds most of the detections names the hand
    flipped = _track(px, cam, depth, _label(300, [(0, 200)], gaps))
    assert flipped.accepted[:, 0].sum() == seen.sum() and not flipped.accepted[:, 1].any()
    # switched off, the bursts are hands of their own: the failure this rule repairs
    off = _track(px, cam, depth, present, one_hand_same_place_sizes=0.0)
    assert off.accepted[:, 0].sum() >= 60 and off.accepted[:, 1].any()


def test_two_hands_one_after_the_other_at_different_places_keep_both_labels():
    """Never in the same frame, but the label changes to another place: the left hand works, then the
    right one, 1.4 hand sizes to its right. Both stay."""
    px, cam, depth = _sequence(T=240)
    px[:, 1, :, 0] += 100                            # 300 px from the left hand
    present = np.zeros((240, 2), bool)
    present[:110, 0] = True
    present[115:, 1] = True
    r = _track(px, cam, depth, present)
    np.testing.assert_array_equal(r.accepted, present)
    assert not r.swapped.any()
    # ... and a one-hand flip happens at the same place, however long the burst
    px1, cam1, depth1 = _one_hand(T=240)
    r = _track(px1, cam1, depth1, _label(240, [(0, 130)]))
    assert r.accepted[:, 0].all() and not r.accepted[:, 1].any()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 239), st.integers(3, 60)), min_size=1, max_size=6),
       st.lists(st.tuples(st.integers(0, 239), st.integers(1, 15)), max_size=4), st.floats(0.3, 1.0),
       st.integers(0, 3))
def test_one_hand_never_yields_two_tracks_whatever_its_label_bursts(bursts, gaps, speed, seed):
    """Whatever the bursts, while the hand is lost for at most max_gap_frames (15) at up to 10 px (0.05
    hand sizes) a frame: it comes back within reach of where it was."""
    px, cam, depth = _one_hand(T=240, speed=speed, seed=seed)
    present = _label(240, [(a, a + n) for a, n in bursts], [(a, a + n) for a, n in gaps])
    lost = np.diff(np.flatnonzero(np.diff(np.concatenate([[1], present.any(axis=1), [1]]).astype(int))))
    assume(lost[0::2].max(initial=0) <= 15)   # the runs without a detection (every other run, from the first)
    r = _track(px, cam, depth, present)
    assert not (r.accepted[:, 0].any() and r.accepted[:, 1].any())
    # no detection is lost to the merge: whatever the labels, one track holds the sustained ones
    assert r.accepted.sum() >= _track(px, cam, depth, present, one_hand_same_place_sizes=0.0).accepted.sum() - 4


def test_a_burst_needs_sustained_evidence_to_be_born():
    px, cam, depth = _sequence()
    present = np.zeros((200, 2), bool)
    present[[20, 24, 40, 41, 60, 70, 71], 0] = True   # never 3 of 5 consecutive frames
    present[100:104, 1] = True                        # 4 in a row but fewer than min_track_detections
    r = _track(px, cam, depth, present)
    assert not r.accepted.any()
    present[120:126, 1] = True
    r = _track(px, cam, depth, present)
    assert r.accepted[120:126, 1].all() and r.accepted[:, 1].sum() == 6


def test_detection_off_its_depth_is_rejected_and_depth_off_switches_the_check():
    px, cam, depth = _sequence()
    depth[30:40, 0] *= 3.0                            # "hand" read on the wall behind it
    present = np.ones((200, 2), bool)
    r = _track(px, cam, depth, present)
    assert (r.reason()[30:40, 0] == "depth_inconsistent").all() and r.accepted[40:, 0].all()
    np.testing.assert_allclose(r.depth_ratio[30:40, 0], 3.0, rtol=0.05)
    r2 = track_hands(px, present, None, joints_cam=cam, anchor_depth=depth, K=K, use_depth=False)
    assert r2.accepted.all()


def test_duplicate_labels_on_one_hand_keep_the_more_confident():
    px, cam, depth = _sequence()
    dup = np.zeros(200, bool)
    dup[80:85] = True
    px[dup, 0], cam[dup, 0] = px[dup, 1] + 0.5, cam[dup, 1]
    conf = np.full((200, 2), 0.9)
    conf[dup, 0] = 0.4
    r = _track(px, cam, depth, np.ones((200, 2), bool), conf)
    assert (r.reason()[dup, 0] == "duplicate").all()
    assert r.accepted[dup, 1].all() and not r.swapped.any()


def test_ratio_detects_units_and_size_helpers():
    px, cam, depth = _sequence(T=5)
    np.testing.assert_allclose(depth_size_ratio(cam, px, depth * 1000, K), 1000, rtol=0.05)
    np.testing.assert_allclose(depth_size_ratio(cam, px, depth / 1000, K), 1e-3, rtol=0.05)
    assert np.isnan(depth_size_ratio(cam, px, np.full_like(depth, np.nan), K)).all()
    assert (hand_size_px(px) > 50).all()


def test_bounded_fill_mask_properties():
    rng = np.random.default_rng(0)
    for _ in range(20):
        good = rng.random((60, 2)) < 0.3
        m = bounded_fill_mask(good, 3)
        assert (m >= good).all()
        t = np.arange(60)
        for h in range(2):
            g = np.flatnonzero(good[:, h])
            for i in np.flatnonzero(m[:, h] & ~good[:, h]):
                before, after = g[g < i], g[g > i]
                gap = (after[0] - before[-1] - 1) if before.size and after.size else \
                    (i - before[-1] if before.size else after[0] - i)
                assert gap <= 3
        assert bounded_fill_mask(good, None).all()
        assert (bounded_fill_mask(np.zeros((60, 2), bool), 5) == 0).all()
        del t


def test_config_validation():
    with pytest.raises(ValueError):
        TrackerConfig(birth_k=6, birth_window=5)
    with pytest.raises(ValueError):
        TrackerConfig(depth_ratio_tol=1.0)
