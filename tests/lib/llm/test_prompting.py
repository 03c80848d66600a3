"""Prompt building (demoforge.lib.llm.prompting; golden file), resampling, rounding and token counting (the
answer parser: test_parsing.py)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import demoforge.lib
from demoforge.lib.llm.prompting import (
    ANSWER_PREFIX, PROMPT_VERSION, SYSTEM_PROMPT, Example, approx_token_count, build_prompt, count_tokens,
    format_actions, format_keypoints, format_number, order_by_similarity, parse_actions, resample_actions,
)
from tests.support.llm import hand_episode, random_episode
from tests.support.paths import GOLDEN as GOLDEN_DIR

GOLDEN = GOLDEN_DIR / "prompt_3demos.txt"


# ------------------------------------------------------------------------------------------------
# fixtures: three small hand-made episodes
# ------------------------------------------------------------------------------------------------

def three_examples() -> list[Example]:
    return [hand_episode(0.0), hand_episode(0.05), hand_episode(-0.04)]


def golden_prompt():
    exs = three_examples()
    q = hand_episode(0.01)
    return build_prompt(exs, q.keypoints, q.initial, n_waypoints=6, precision=3)


# ------------------------------------------------------------------------------------------------
# prompt
# ------------------------------------------------------------------------------------------------

def test_prompt_matches_golden_file():
    p = golden_prompt()
    rendered = p.render() + f"content_hash: {p.content_hash}\n"
    if os.environ.get("DEMOFORGE_UPDATE_GOLDEN") == "1":
        GOLDEN.parent.mkdir(parents=True, exist_ok=True)
        GOLDEN.write_text(rendered, encoding="utf-8")
    assert GOLDEN.exists(), "run once with DEMOFORGE_UPDATE_GOLDEN=1 to write the golden file"
    assert rendered == GOLDEN.read_text(encoding="utf-8")


def test_prompt_structure():
    p = golden_prompt()
    assert p.n_examples == 3 and p.n_waypoints == 6 and p.n_keypoints == 11
    assert [m["role"] for m in p.messages] == ["system", "user"]
    assert p.system.startswith("You are a dual-arm robot controller.")
    assert "Only output the action list." in p.system
    for i in range(3):
        assert f"** Demo {i} **" in p.user
    assert p.user.count("** New Input **") == 1
    assert p.user.count("Action Sequence:") == 3
    assert p.user.count("# shape: (6, 2, 8)") == 3
    assert p.user.count("# shape: (11, 3)") == 4
    assert p.user.rstrip().endswith("# shape: (2, 8)")
    assert p.text.endswith("Action Sequence:\n" + ANSWER_PREFIX)
    assert p.text.startswith(p.system) and p.user in p.text
    # stable hash: same content -> same hash; different content -> different hash
    assert golden_prompt().content_hash == p.content_hash
    exs = three_examples()
    q = hand_episode(0.02)
    assert build_prompt(exs, q.keypoints, q.initial, n_waypoints=6).content_hash != p.content_hash
    assert build_prompt(exs, hand_episode(0.01).keypoints, q.initial, n_waypoints=6, precision=2).content_hash \
        != p.content_hash


def test_demo_actions_in_prompt_parse_back():
    p = golden_prompt()
    block = p.user.split("Action Sequence:\n")[1].split("\n# shape")[0]
    res = parse_actions(block)
    assert res.status == "ok" and res.actions.shape == (6, 2, 8)
    ref = resample_actions(three_examples()[0].actions, 6)
    assert np.allclose(res.actions[:, :, :3], ref[:, :, :3], atol=6e-4)
    assert np.array_equal(res.actions[:, :, 7], ref[:, :, 7])


THESIS = demoforge.lib.SHARED_DATA.parent / "reference" / "thesis.txt"


def test_system_prompt_is_the_thesis_appendix_a_word_for_word():
    """The system message is the text of Appendix A's SYSTEM_PROMPT (between its opening quotes and
    FORMAT_PROMPT; the extraction never closes the string), with the task's keypoint count for 11."""
    if not THESIS.is_file():
        pytest.skip(f"{THESIS} absent (the thesis text lives next to ../shared/data)")
    text = THESIS.read_text(encoding="utf-8")
    start = text.index('SYSTEM_PROMPT = """\n') + len('SYSTEM_PROMPT = """\n')
    thesis_system = text[start:text.index("FORMAT_PROMPT", start)].rstrip("\n")
    assert SYSTEM_PROMPT.format(k=11) == thesis_system
    p = golden_prompt()
    assert p.system == thesis_system


def test_keyframe_prompt_is_the_default_and_asks_for_the_last_examples_count():
    from demoforge.lib.trajectories.keyframes import DEFAULT_KEYFRAMES, KeyframeSettings, keyframe_actions

    exs = [hand_episode(0.0, n=40), hand_episode(0.05, n=30)]
    q = hand_episode(0.01)
    p = build_prompt(exs, q.keypoints, q.initial)
    assert p.encoding == "keyframes" and p.version == PROMPT_VERSION == "appendix-a-v2-keyframes"
    kf = [keyframe_actions(e.actions, DEFAULT_KEYFRAMES) for e in exs]
    idx = [i for _, i in kf]
    for (values, i) in kf:
        assert f"# shape: ({len(i)}, 2, 8)" in p.user
        assert format_actions(values) in p.user  # the keyframes of the smoothed sequence
    # other settings (a task's own) write other keyframes
    fine_settings = KeyframeSettings(0.0002, 0.002, 1.0)
    fine = build_prompt(exs, q.keypoints, q.initial, keyframes=fine_settings)
    assert fine.n_waypoints > p.n_waypoints
    assert format_actions(keyframe_actions(exs[-1].actions, fine_settings)[0]) in fine.user
    assert p.n_waypoints == len(idx[-1]) and np.allclose(p.keyframe_times, idx[-1] / 29)
    # explicit waypoints keep today's uniform resampling; the encodings never share a content hash
    u = build_prompt(exs, q.keypoints, q.initial, n_waypoints=6)
    assert u.encoding == "uniform" and u.n_waypoints == 6 and u.keyframe_times == ()
    r = build_prompt(exs, q.keypoints, q.initial, encoding="raw")
    assert r.n_waypoints == 30 and len({p.content_hash, u.content_hash, r.content_hash}) == 3
    with pytest.raises(ValueError):
        build_prompt(exs, q.keypoints, q.initial, encoding="uniform")
    with pytest.raises(ValueError):
        build_prompt(exs, q.keypoints, q.initial, encoding="bogus")


def test_examples_ordered_with_the_most_similar_last():
    q = hand_episode(0.01)
    exs = [hand_episode(0.0), hand_episode(0.08), hand_episode(-0.04)]  # MSE order: 0 < 2 < 1
    ordered = order_by_similarity(exs, q.keypoints)
    assert [o.keypoints[0, 0] for o in ordered] == [exs[i].keypoints[0, 0] for i in (1, 2, 0)]
    p = build_prompt(ordered, q.keypoints, q.initial)
    last = p.user.split("** Demo 2 **")[1].split("** New Input **")[0]
    assert format_keypoints(exs[0].keypoints) in last  # the nearest example sits next to the new input
    assert format_keypoints(exs[1].keypoints) in p.user.split("** Demo 1 **")[0]


def test_build_prompt_accepts_tuples_and_dicts():
    e = hand_episode(0.0)
    p1 = build_prompt([e], e.keypoints, e.initial, n_waypoints=5)
    p2 = build_prompt([(e.keypoints, e.initial, e.actions)], e.keypoints, e.initial, n_waypoints=5)
    p3 = build_prompt([{"keypoints": e.keypoints, "initial": e.initial, "actions": e.actions}],
                      e.keypoints, e.initial, n_waypoints=5)
    assert p1.content_hash == p2.content_hash == p3.content_hash
    with pytest.raises(ValueError):
        build_prompt([e], e.keypoints[:5], e.initial)


def test_format_number():
    assert format_number(0.12004) == "0.12"
    assert format_number(1.0) == "1"
    assert format_number(-0.0001) == "0"
    assert format_number(-0.25) == "-0.25"
    assert format_number(0.123456, 4) == "0.1235"
    assert format_number(12.5, 0) == "12" and format_number(13.5, 0) == "14"  # ties to even, like round()


def test_token_counts_and_compactness():
    p = build_prompt(three_examples(), hand_episode(0.01).keypoints, hand_episode(0.01).initial, n_waypoints=20)
    n = count_tokens(p.text)
    # without a tokenizer: 1 per digit, symbol and newline, ceil(len / 4) per word, spaces free
    assert count_tokens("Keypoints up 0.25,\n[1]") == approx_token_count("Keypoints up 0.25,\n[1]") == 3 + 1 + 4 + 1 + 1 + 3
    # three demos of 20 waypoints stay well inside a small model's context
    assert 3000 < n < 12000

    class WithTokenizer:
        def count_tokens(self, text):
            return 7

    assert count_tokens("anything", WithTokenizer()) == 7


# ------------------------------------------------------------------------------------------------
# resampling
# ------------------------------------------------------------------------------------------------

def test_resample_keeps_endpoints_and_gripper_changes():
    rng = np.random.default_rng(1)
    a = random_episode(rng, 137, changes_left=(40, 101), changes_right=(55,))
    r = resample_actions(a, 20)
    assert r.shape == (20, 2, 8)
    assert np.allclose(r[0], a[0]) and np.allclose(r[-1], a[-1])
    # every change of the original appears, as an exact waypoint with the original pose
    for t in (40, 55, 101):
        hits = [i for i in range(20) if np.allclose(r[i], a[t])]
        assert hits, f"change step {t} is not a waypoint"
    # same sequence of gripper transitions per arm
    for arm in (0, 1):
        orig = a[:, arm, 7][np.r_[True, np.diff(a[:, arm, 7]) != 0]]
        new = r[:, arm, 7][np.r_[True, np.diff(r[:, arm, 7]) != 0]]
        assert np.array_equal(orig, new)
    assert set(np.unique(r[:, :, 7])) <= {0.0, 1.0}
    assert np.allclose(np.linalg.norm(r[:, :, 3:7], axis=-1), 1.0)


def test_resample_interpolation_and_shapes():
    rng = np.random.default_rng(2)
    a = random_episode(rng, 5)
    a[:, :, :3] = np.arange(5)[:, None, None] * np.array([1.0, 2.0, 3.0])
    r = resample_actions(a, 9)  # upsampling: linear positions on a line
    assert r.shape == (9, 2, 8)
    assert np.allclose(r[:, 0, 0], np.linspace(0, 4, 9))
    assert resample_actions(a[:1], 4).shape == (4, 2, 8)
    with pytest.raises(ValueError):
        resample_actions(a, 1)
    with pytest.raises(ValueError):
        resample_actions(a[:, :, :7], 5)


def test_resample_too_many_changes_keeps_what_fits():
    rng = np.random.default_rng(3)
    a = random_episode(rng, 60, changes_left=tuple(range(5, 55, 4)))  # 13 changes
    r = resample_actions(a, 8)
    assert r.shape == (8, 2, 8)
    assert np.allclose(r[0], a[0]) and np.allclose(r[-1], a[-1])


def test_a_prompt_without_examples_is_refused():
    from demoforge.lib.llm.prompting import build_prompt
    from tests.support.llm import demo

    ex = demo(n=4)
    with pytest.raises(ValueError, match="at least one example"):
        build_prompt([], ex[0], ex[1], n_waypoints=4)
