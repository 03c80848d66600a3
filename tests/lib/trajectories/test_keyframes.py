"""Keyframe encoding of action sequences: bounded reconstruction error, gripper instants, idempotence,
exactness on piecewise linear trajectories, and the executor's interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from demoforge.lib.geometry import interpolate_poses, quat_slerp
from demoforge.lib.trajectories.keyframes import (
    KeyframeSettings, answer_times, decode_keyframes, encode_keyframes, gripper_change_steps,
    keyframe_actions, keyframe_fractions, reconstruction_error, smooth_actions,
)

TINY = 1e-9


def _unit(q):
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@st.composite
def trajectories(draw, max_steps=70):
    """A (T, 2, 8) random-walk trajectory: positions and orientations drift (some steps still, some
    large), gripper values switch at random steps, quaternion signs flip at random (same rotation)."""
    T = draw(st.integers(1, max_steps))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    # position and rotation drift drawn apart: each tolerance must hold on its own
    scale = draw(st.sampled_from([0.0, 0.001, 0.01, 0.05]))
    rot_scale = draw(st.sampled_from([0.0, 0.01, 0.03, 0.2]))
    a = np.zeros((T, 2, 8))
    a[:, :, :3] = np.cumsum(rng.normal(scale=scale, size=(T, 2, 3)), axis=0)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (T, 2, 1)) + np.cumsum(rng.normal(scale=rot_scale, size=(T, 2, 4)), axis=0)
    q = _unit(q)
    q *= np.where(rng.random((T, 2, 1)) < 0.2, -1.0, 1.0)
    a[:, :, 3:7] = q
    flips = rng.random((T, 2)) < draw(st.sampled_from([0.0, 0.05, 0.3]))
    a[:, :, 7] = (np.cumsum(flips, axis=0) % 2 == 0).astype(float)
    return a


@settings(max_examples=60, deadline=None)
@given(trajectories(), st.sampled_from([(0.005, 0.05), (0.001, 0.01), (0.02, 0.2), (TINY, TINY)]))
def test_reconstruction_within_tolerance_and_gripper_kept(a, tol):
    idx = encode_keyframes(a, *tol)
    T = len(a)
    assert idx[0] == 0 and idx[-1] == T - 1 and np.all(np.diff(idx) > 0)
    d = decode_keyframes(a[idx], idx, T)
    dp, dq = reconstruction_error(a, d)
    assert dp.max() <= tol[0] + 1e-9 and dq.max() <= tol[1] + 1e-7
    # every open/close instant on both sides, so the decoded gripper values are the original ones
    ch = gripper_change_steps(a)
    assert set(ch.tolist()) <= set(idx.tolist()) and set((ch - 1).tolist()) <= set(idx.tolist())
    assert np.array_equal(d[:, :, 7], a[:, :, 7])
    assert np.array_equal(d[idx], a[idx])  # keyframes decode to themselves


@settings(max_examples=40, deadline=None)
@given(trajectories(), st.lists(st.integers(-3, 80), max_size=5))
def test_boundaries_are_kept(a, boundaries):
    idx = set(encode_keyframes(a, boundaries=boundaries).tolist())
    assert {b for b in boundaries if 0 <= b < len(a)} <= idx


@settings(max_examples=40, deadline=None)
@given(trajectories(), st.sampled_from([(0.005, 0.05), (0.02, 0.2)]))
def test_idempotent(a, tol):
    """The decoded trajectory is exactly what its keyframes say: encoding it again (zero tolerance)
    keeps no step that is not already a keyframe and decodes to it exactly; with the original
    tolerances it needs no more keyframes."""
    idx = encode_keyframes(a, *tol)
    y = decode_keyframes(a[idx], idx, len(a))
    again = encode_keyframes(y, TINY, TINY)
    assert set(again.tolist()) <= set(idx.tolist())
    assert np.allclose(decode_keyframes(y[again], again, len(a)), y, atol=1e-9)
    assert len(encode_keyframes(y, *tol)) <= len(idx)


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 8), st.integers(0, 2**32 - 1))
def test_decode_of_encode_of_piecewise_linear_is_exact(n_knots, seed):
    rng = np.random.default_rng(seed)
    T = int(rng.integers(n_knots, 60))
    knots = np.unique(np.concatenate([[0, T - 1], rng.choice(T, size=n_knots - 2, replace=True)])) if T > 1 else [0]
    kf = np.zeros((len(knots), 2, 8))
    kf[:, :, :3] = rng.normal(scale=0.2, size=(len(knots), 2, 3))
    kf[:, :, 3:7] = _unit(rng.normal(size=(len(knots), 2, 4)))
    kf[:, :, 7] = 1.0
    x = decode_keyframes(kf, knots, T)
    idx = encode_keyframes(x, TINY, TINY)
    assert set(idx.tolist()) <= set(np.asarray(knots).tolist())
    back = decode_keyframes(x[idx], idx, T)
    assert np.allclose(back[..., :3], x[..., :3], atol=1e-9)
    dp, dq = reconstruction_error(x, back)
    assert dq.max() < 1e-6
    # a straight, constant-speed trajectory needs only its two ends
    line = decode_keyframes(kf[[0, -1]], [0, T - 1], T)
    assert len(encode_keyframes(line, TINY, TINY)) == min(T, 2)


def test_decoded_steps_execute_like_the_keyframes():
    """The executor slerps / lerps between consecutive steps: on the decoded steps that is the same
    motion as interpolating the keyframes themselves at any sub-step time."""
    rng = np.random.default_rng(3)
    T = 40
    kf = np.zeros((4, 2, 8))
    kf[:, :, :3] = rng.normal(scale=0.1, size=(4, 2, 3))
    kf[:, :, 3:7] = _unit(rng.normal(size=(4, 2, 4)))
    t_kf = np.array([0, 7, 20, 39])
    steps = decode_keyframes(kf, t_kf, T)
    tq = np.linspace(0, T - 1, 500)
    p1, q1 = interpolate_poses(np.arange(T), steps[..., :3], steps[..., 3:7], tq, rotation="slerp", position="linear")
    p2, q2 = interpolate_poses(t_kf, kf[..., :3], kf[..., 3:7], tq, rotation="slerp", position="linear")
    assert np.allclose(p1, p2, atol=1e-9)
    assert np.allclose(np.abs(np.sum(q1 * q2, axis=-1)), 1.0, atol=1e-9)


def test_gripper_change_instants_reproduced_at_the_same_step():
    T = 30
    a = np.zeros((T, 2, 8))
    a[:, :, 0] = np.linspace(0, 0.3, T)[:, None]  # a straight line: only forced keyframes
    a[:, :, 6] = 1.0
    a[:, 0, 7] = (np.arange(T) < 12).astype(float)  # left closes at 12
    a[:, 1, 7] = ((np.arange(T) < 5) | (np.arange(T) >= 20)).astype(float)  # right closes at 5, opens at 20
    idx = encode_keyframes(a)
    assert idx.tolist() == [0, 4, 5, 11, 12, 19, 20, 29]
    d = decode_keyframes(a[idx], idx, T)
    assert np.array_equal(d[:, :, 7], a[:, :, 7]) and np.allclose(d, a, atol=1e-12)


def _noisy_arc(T=300, noise_m=0.009, noise_rad=0.1, seed=0):
    """Two arms moving along a smooth arc while turning slowly, gripper closing once per arm, with
    per-step jitter of the size an ingested take carries: (clean, noisy)."""
    from demoforge.lib.geometry import quat_exp, quat_multiply

    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, T)
    a = np.zeros((T, 2, 8))
    for arm, sign in enumerate((1.0, -1.0)):
        a[:, arm, 0] = sign * 0.2 * np.sin(np.pi * t)
        a[:, arm, 1] = 0.3 * t
        a[:, arm, 2] = 0.1 + 0.05 * np.cos(2 * np.pi * t)
        a[:, arm, 3:7] = quat_exp(np.stack([0.5 * t, 0.0 * t, sign * 0.8 * t], axis=-1))
    a[:, 0, 7] = (np.arange(T) < 90).astype(float)
    a[:, 1, 7] = (np.arange(T) < 150).astype(float)
    noisy = a.copy()
    noisy[:, :, :3] += rng.normal(scale=noise_m / np.sqrt(3), size=(T, 2, 3))
    noisy[:, :, 3:7] = quat_multiply(quat_exp(rng.normal(scale=noise_rad / np.sqrt(3), size=(T, 2, 3))), a[:, :, 3:7])
    return a, noisy


def test_smoothing_keeps_the_gripper_and_a_straight_line_and_removes_jitter():
    clean, noisy = _noisy_arc()
    assert np.array_equal(smooth_actions(noisy, 0.0), noisy)
    sm = smooth_actions(noisy, 3.0)
    assert np.array_equal(sm[:, :, 7], noisy[:, :, 7])
    assert np.allclose(np.linalg.norm(sm[:, :, 3:7], axis=-1), 1.0)
    # jitter: the smoothed poses lie far closer to the clean ones than the noisy ones do
    err_noisy, rot_noisy = reconstruction_error(clean, noisy)
    err_sm, rot_sm = reconstruction_error(clean, sm)
    assert np.median(err_sm) < 0.5 * np.median(err_noisy)
    assert np.median(rot_sm) < 0.5 * np.median(rot_noisy)
    # a constant-velocity straight line is its own Gaussian average (away from the clamped ends)
    line = np.zeros((50, 2, 8))
    line[:, :, :3] = np.linspace(0, 1, 50)[:, None, None] * np.array([0.1, -0.2, 0.05])
    line[:, :, 6] = 1.0
    assert np.allclose(smooth_actions(line, 2.0)[10:-10], line[10:-10], atol=1e-12)
    # a quaternion sign flip (the same rotation) does not drag the average through zero
    flipped = noisy.copy()
    flipped[::2, :, 3:7] *= -1
    assert np.allclose(np.abs(np.sum(smooth_actions(flipped, 3.0)[:, :, 3:7] * sm[:, :, 3:7], axis=-1)), 1.0)


def test_keyframes_of_a_jittery_sequence_are_few_and_follow_the_smoothed_one():
    clean, noisy = _noisy_arc()
    unsmoothed = encode_keyframes(noisy, 0.005, 0.05)
    s = KeyframeSettings(0.01, 0.1, 3.0)
    values, idx = keyframe_actions(noisy, s)
    assert len(unsmoothed) > 0.8 * len(noisy)  # the jitter defeats the encoder alone
    assert len(idx) < 0.15 * len(noisy)
    # the keyframes are the smoothed poses at the kept steps; decoding them stays within the
    # tolerances of the smoothed sequence and keeps every gripper instant
    sm = smooth_actions(noisy, 3.0)
    assert np.array_equal(values, sm[idx])
    dp, dq = reconstruction_error(sm, decode_keyframes(values, idx, len(noisy)))
    assert dp.max() <= s.pos_tol_m + 1e-9 and dq.max() <= s.rot_tol_rad + 1e-9
    assert set(gripper_change_steps(noisy).tolist()) <= set(idx.tolist())
    with pytest.raises(ValueError, match=">= 0"):
        KeyframeSettings(-0.01, 0.1, 1.0)


def test_answer_times():
    idx = np.array([0, 4, 5, 11, 12, 29])
    f = keyframe_fractions(idx, 30)
    assert np.array_equal(answer_times(f, 6, 30), idx)  # the same count, the same length: the example's steps
    assert np.allclose(answer_times(f, 6, 59), idx * 2)  # scaled to the answer's length
    t = answer_times(f, 9, 30)  # another count: spread over the example's time curve
    assert len(t) == 9 and t[0] == 0 and t[-1] == 29 and np.all(np.diff(t) > 0)
    t = answer_times(f, 40, 10)  # more keyframes than steps: fractional times, still increasing
    assert len(t) == 40 and t[-1] == 9 and np.all(np.diff(t) > 0)
    assert np.array_equal(answer_times([0.0, 0.0, 1.0], 3, 10), [0, 4.5, 9])  # degenerate curve: even spread
    with pytest.raises(ValueError):
        answer_times(f, 0, 30)


def test_bad_inputs():
    with pytest.raises(ValueError):
        encode_keyframes(np.zeros((5, 2, 7)))
    with pytest.raises(ValueError):
        decode_keyframes(np.zeros((3, 2, 8)), [0, 1], 5)
    one = np.zeros((1, 2, 8))
    one[:, :, 6] = 1
    assert encode_keyframes(one).tolist() == [0]
    assert decode_keyframes(one, [0], 4).shape == (4, 2, 8)


def test_keyframe_round_trip_in_physics():
    """Database episodes executed in MuJoCo raw and keyframe-encoded -> decoded: the decoded ones
    succeed wherever the raw ones do (the full table: scripts/measure_keyframes.py)."""
    from demoforge.lib.sim import execute
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

    spec = get_task("trash_in_bin")
    db = generate_episodes(from_scripted_demo(spec, spec.scripted_demo(0)), n=12, n_mirrored=6, seed=2)
    ids = [i for i in np.flatnonzero(db.valid) if i > 0]
    ids = [ids[0], ids[1], ids[-1]]  # two translated episodes and a mirrored one
    assert db.kind[ids[-1]] == "mirrored"
    raw_ok = []
    for i, a in zip(ids, db.episode_actions(ids)):
        a = a[:db.lengths[i]]
        values, idx = keyframe_actions(a, spec.keyframes)  # what the task's prompts write
        assert len(idx) < len(a) / 6
        raw = execute("trash_in_bin", db.keypoints[i], a)
        dec = execute("trash_in_bin", db.keypoints[i], decode_keyframes(values, idx, len(a)))
        raw_ok.append(raw.success)
        assert dec.success or not raw.success, (i, dec.failure, dec.detail)
        # the check can tell: only the forced keyframes (ends and gripper instants, no tolerance) fail
        crude = encode_keyframes(a, 1.0, 10.0)
        assert not execute("trash_in_bin", db.keypoints[i], decode_keyframes(a[crude], crude, len(a))).success
    assert any(raw_ok)
