"""The tolerant answer parser (demoforge.lib.llm.parsing): clean and markdown answers, Python and numpy
spellings, continuations, bad and truncated answers, normalisation, and the round trip with the prompt's
format."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from demoforge.lib.llm.parsing import PARSE_STATUSES, parse_actions
from demoforge.lib.llm.prompting import format_actions, format_number
from tests.support.llm import random_episode


def _valid(n=4, seed=0):
    rng = np.random.default_rng(seed)
    return random_episode(rng, n, changes_left=(2,))


def test_parse_clean_and_markdown():
    a = _valid()
    s = format_actions(a)
    for text in (s, f"```json\n{s}\n```", f"```python\nactions = {s}\n```\n",
                 f"Sure! Here is the action sequence:\n\n{s}\n\nThis moves the right arm to the cup.",
                 s.replace(",", ", ").replace("\n", " ")):
        res = parse_actions(text, expected_waypoints=4)
        assert res.status == "ok", (res.status, res.detail, text[:60])
        assert res.actions.shape == (4, 2, 8)
        assert np.allclose(res.actions[:, :, :3], np.round(a[:, :, :3], 3))
        assert res.raw == text


def test_parse_python_numpy_and_exponents():
    a = _valid()
    np_style = "array(" + np.array2string(a, separator=", ", threshold=10**6) + ")"
    res = parse_actions(np_style)
    assert res.status == "ok" and np.allclose(res.actions[:, :, :3], a[:, :, :3], atol=1e-6)
    no_commas = np.array2string(a, threshold=10**6)  # numpy print without commas
    res = parse_actions(no_commas)
    assert res.status == "ok" and np.allclose(res.actions[:, :, :3], a[:, :, :3], atol=1e-6)
    r2 = parse_actions("[[[1e-1, 2.5E-2, -3e+0, 0, 0, 0, 1, 1], [1, 2, 3, 0, 0, 0, 2, 0]],"
                       " [[.1, -.2, 3., 0, 1e0, 0, 0, 0.7], [1, 2, 3, 0, 0, 0, 1, 0.2]]]")
    assert r2.status == "ok"
    assert np.allclose(r2.actions[0, 0, :3], [0.1, 0.025, -3.0])
    assert np.allclose(r2.actions[1, 0, :3], [0.1, -0.2, 3.0])
    assert np.allclose(r2.actions[0, 1, 3:7], [0, 0, 0, 1])  # normalised
    assert np.array_equal(r2.actions[:, :, 7], [[1, 0], [1, 0]])  # snapped


def test_parse_completion_continuing_prefix():
    a = _valid(5)
    s = format_actions(a)
    assert s.startswith("[[[")
    cont = s[3:] + "\n# shape: (5, 2, 8)\n** Demo 3 **\nInput Keypoints:\n[[0.1,0.2,0.3]]"
    res = parse_actions(cont)
    assert res.status == "ok" and res.actions.shape == (5, 2, 8)
    assert np.allclose(res.actions[:, :, :3], np.round(a[:, :, :3], 3))
    # continuation cut in the middle
    cut = s[3: len(s) * 3 // 4]
    res = parse_actions(cut)
    assert res.status == "truncated" and res.actions is not None and res.n_kept >= 2
    assert "kept" in res.detail


def test_parse_waypoints_without_outer_brackets():
    a = _valid(3)
    inner = format_actions(a)[1:-1]  # "[[..],[..]],\n[[..],[..]],\n..."
    res = parse_actions("Actions:\n" + inner + "\nDone.")
    assert res.status == "ok" and res.actions.shape == (3, 2, 8)


@pytest.mark.parametrize("text,status", [
    ("", "empty"),
    ("   \n\t ", "empty"),
    (None, "empty"),
    ("I cannot predict the trajectory for this scene.", "no_array"),
    ("The robot should move 5 cm to the left and then close the gripper.", "no_array"),
    ("[[[0.1,0.2,0.3,0,0,0,1],[0.1,0.2,0.3,0,0,0,1]],[[0.1,0.2,0.3,0,0,0,1],[0.1,0.2,0.3,0,0,0,1]]]",
     "wrong_shape"),  # (n, 2, 7)
    ("[[[0.1,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]]]", "wrong_shape"),  # (1, 3, 8)
    ("[[0.1,0.2,0.3],[0.4,0.5,0.6]]", "wrong_shape"),
    ("[[[0.1,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]],[[0.1,0.2,0.3,0,0,0,1,1]]]", "wrong_shape"),  # ragged
    ("[[[nan,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]]]", "non_finite"),
    ("[[[0.1,Infinity,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]]]", "non_finite"),
    ("[[[0.1,0.2,1e999,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]]]", "non_finite"),
    ("[[[0.1,0.2,0.3,0,0,0,0,1],[0.1,0.2,0.3,0,0,0,1,1]]]", "zero_quaternion"),
    ("[[[0.1,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,1]],[[0.1,0.2", "truncated"),  # 1 complete waypoint
    ("[[[0.1, foo, 0.3, {}, 0, 0, 1, 1], [[[[]]]]", "wrong_shape"),  # nested garbage
    ("[[[[[[[[[[", "truncated"),
    ("]]]]]] ,,, [[ ]] [ ] {\"a\": [}", "wrong_shape"),
])
def test_parse_bad_answers(text, status):
    res = parse_actions(text)
    assert res.status == status, (res.status, res.detail)
    assert res.status in PARSE_STATUSES
    if status != "truncated":
        assert res.actions is None
    assert isinstance(res.detail, str)


def test_parse_real_gemma_answer_with_a_dropped_bracket():
    # what the local Gemma 270M produced: the 4th waypoint lost its opening bracket
    w = "[0.21,0.12,0.15,0,0,0.247,0.969,1],[0.21,0.05,0.18,0,0,-0.149,0.989,1]]"
    text = "0.24,0.12,0.15,0,0,0.247,0.969,1],[0.21,0.05,0.18,0,0,-0.149,0.989,1]],\n" + ",\n".join(
        ["[" + w] * 2 + [w] * 4) + ",\n[0.21,0.12,0.15"
    res = parse_actions(text)
    assert res.actions is None and res.status == "wrong_shape"


def test_parse_truncated_keeps_complete_waypoints():
    a = _valid(6)
    s = format_actions(a)
    cut_at = s.index("],\n[[", s.index("],\n[[", s.index("],\n[[") + 1) + 1) + 8  # inside the 4th waypoint
    res = parse_actions("Here you go:\n" + s[:cut_at])
    assert res.status == "truncated" and res.n_kept == 3 and res.actions.shape == (3, 2, 8)
    assert "kept 3" in res.detail


def test_parse_takes_first_good_array_and_skips_bad_ones():
    a, b = _valid(3, seed=1), _valid(4, seed=2)
    text = ("keypoints: [[0.1,0.2,0.3],[0.3,0.2,0.1]]\n" + format_actions(a) + "\nor maybe\n" + format_actions(b))
    res = parse_actions(text)
    assert res.status == "ok" and res.actions.shape == (3, 2, 8)
    res = parse_actions(text, expected_waypoints=4)
    assert res.status == "ok" and "expected 4" in res.detail


def test_parse_quaternion_normalisation_and_gripper_snap():
    res = parse_actions("[[[0,0,0, 0,0,0,2, 0.51],[0,0,0, 0,3,4,0, 0.49]],[[0,0,0, 1,1,1,1, 7],[0,0,0, 0,0,-5,0, -3]]]")
    assert res.status == "ok"
    q = res.actions[:, :, 3:7]
    assert np.allclose(np.linalg.norm(q, axis=-1), 1)
    assert np.allclose(q[0, 1], [0, 0.6, 0.8, 0])
    assert np.array_equal(res.actions[:, :, 7], [[1, 0], [1, 0]])


def test_parse_never_raises_on_junk():
    rng = np.random.default_rng(0)
    alphabet = list("[],.-+eE0123456789 \nnaifNAI{}\"':x`")
    for _ in range(300):
        s = "".join(rng.choice(alphabet, size=rng.integers(0, 200)))
        res = parse_actions(s)
        assert res.status in PARSE_STATUSES
    for weird in (b"[[[1]]]", 12, object(), ["[[["], "\x00\x01[[[", "[" * 5000 + "]" * 4000):
        assert parse_actions(weird).status in PARSE_STATUSES


@st.composite
def action_arrays(draw):
    n = draw(st.integers(1, 25))
    pos = draw(arrays(np.float64, (n, 2, 3), elements=st.floats(-2, 2, allow_nan=False, allow_infinity=False)))
    q = draw(arrays(np.float64, (n, 2, 4), elements=st.floats(-1, 1, allow_nan=False, allow_infinity=False)))
    norms = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norms < 1e-3, np.array([0.0, 0.0, 0.0, 1.0]), q / np.maximum(norms, 1e-12))
    g = draw(arrays(np.float64, (n, 2, 1), elements=st.sampled_from([0.0, 1.0])))
    return np.concatenate([pos, q, g], axis=-1)


@settings(max_examples=150, deadline=None)
@given(a=action_arrays(), precision=st.integers(1, 6), continuation=st.booleans())
def test_format_parse_round_trip(a, precision, continuation):
    s = format_actions(a, precision)
    text = s[3:] if continuation else s
    res = parse_actions(text)
    assert res.status == "ok", (res.status, res.detail)
    assert res.actions.shape == a.shape
    # positions come back exactly as rounded; quaternions as the normalised rounded values
    rounded = np.array([[[float(format_number(v, precision)) for v in arm] for arm in w] for w in a])
    assert np.allclose(res.actions[:, :, :3], rounded[:, :, :3], rtol=0, atol=1e-12)
    qr = rounded[:, :, 3:7]
    assert np.allclose(res.actions[:, :, 3:7], qr / np.linalg.norm(qr, axis=-1, keepdims=True), atol=1e-12)
    assert np.array_equal(res.actions[:, :, 7], a[:, :, 7])
    assert np.all(np.abs(res.actions[:, :, :3] - a[:, :, :3]) <= 0.5 * 10.0 ** -precision + 1e-12)
