"""The compact number format: what is written reads back within its rounding, and costs fewer tokens."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from demoforge.lib.geometry import quat_angle, quat_normalize
from demoforge.lib.llm.number_format import NUMBER_FORMATS, get_number_format
from demoforge.lib.llm.prompting import approx_token_count, format_actions

COMPACT = NUMBER_FORMATS["compact"]


def _poses(raw: np.ndarray) -> np.ndarray:
    p = raw.copy()
    p[..., 3:7] = quat_normalize(p[..., 3:7] + np.array([1.0, 0, 0, 0]) * (np.linalg.norm(p[..., 3:7], axis=-1,
                                                                                         keepdims=True) < 1e-3))
    p[..., 7] = (p[..., 7] > 0).astype(float)
    return p


@settings(max_examples=60)
@given(arrays(np.float64, (5, 2, 8), elements=st.floats(-0.9, 0.9, allow_nan=False)))
def test_compact_reads_back_within_its_rounding(raw):
    poses = _poses(raw)
    written = np.round(COMPACT.encode_poses(poses))  # what the prompt shows (integers)
    back = COMPACT.decode_poses(written)
    assert np.abs(back[..., :3] - poses[..., :3]).max() <= 0.0005 + 1e-12  # half a millimetre
    # hundredths of each component: the rotation is off by at most ~0.6 degrees
    assert quat_angle(back[..., 3:7], poses[..., 3:7]).max() < 0.025
    assert np.array_equal(back[..., 7], poses[..., 7])


def test_thesis_format_writes_metres_unchanged():
    fmt = get_number_format(None)
    poses = _poses(np.random.default_rng(0).uniform(-0.5, 0.5, (3, 2, 8)))
    assert fmt.name == "thesis" and fmt.precision(3) == 3 and fmt.system_note == ""
    assert np.array_equal(fmt.encode_poses(poses), poses)
    assert np.allclose(fmt.decode_poses(poses), poses)


def test_compact_costs_fewer_tokens_than_the_thesis_format():
    poses = _poses(np.random.default_rng(1).uniform(-0.5, 0.5, (20, 2, 8)))
    thesis = approx_token_count(format_actions(poses, 3))
    compact = approx_token_count(format_actions(COMPACT.encode_poses(poses), COMPACT.precision(3)))
    assert compact < 0.75 * thesis, (compact, thesis)


def test_unknown_format_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="thesis, compact"):
        get_number_format("hex")


# ------------------------------------------------------------------------------------------------
# a compact prompt end to end: what the model sees, the grammar it answers under, how it is read back
# ------------------------------------------------------------------------------------------------

def _compact_prompt(n_waypoints=4):
    from demoforge.lib.llm.prompting import build_prompt
    from tests.support.llm import demo

    ex = demo(n=6)
    return ex, build_prompt([ex], ex[0] + 0.01, ex[1], n_waypoints=n_waypoints, number_format="compact")


def test_a_compact_prompt_writes_integers_and_says_so():
    from demoforge.lib.llm.prompting import SYSTEM_PROMPT, build_prompt
    from tests.support.llm import demo

    ex, p = _compact_prompt()
    assert p.number_format == "compact" and p.precision == 0
    assert p.system == SYSTEM_PROMPT.format(k=11) + "\n" + COMPACT.system_note
    assert "." not in p.user  # every number an integer
    thesis = build_prompt([ex], ex[0] + 0.01, ex[1], n_waypoints=4)
    assert thesis.system == SYSTEM_PROMPT.format(k=11) and thesis.number_format == "thesis"
    assert approx_token_count(p.text) < approx_token_count(thesis.text)  # (real poses: see above, < 0.75)
    # the thesis format is what it was: the default prompt did not change
    assert build_prompt([demo(n=6)], ex[0] + 0.01, ex[1], n_waypoints=4, number_format="thesis").hash == thesis.hash


def test_an_answer_copied_from_a_compact_example_is_read_back_in_metres():
    from demoforge.lib.llm import FakeBackend
    from demoforge.lib.llm.prompting import resample_actions
    from demoforge.tasks.llm_eval import llm_predict

    ex, p = _compact_prompt()
    # the model copies the example's action block as the prompt writes it (integers, mm)
    block = p.user.split("Action Sequence:\n")[1].split("\n# shape")[0]
    backend = FakeBackend(lambda prompt, s: block[len(prompt.answer_prefix):])
    actions, fields = llm_predict(backend, [ex], ex[0] + 0.01, ex[1], n_steps=4, n_waypoints=4,
                                  number_format="compact")
    assert fields["parse_status"] == "ok", fields
    expected = resample_actions(ex[2], 4)
    assert np.abs(actions[..., :3] - expected[..., :3]).max() <= 0.0005 + 1e-9  # metres again, not mm
    assert np.allclose(np.linalg.norm(actions[..., 3:7], axis=-1), 1.0)


def test_the_grammar_of_a_compact_prompt_admits_its_integers_only():
    from demoforge.lib.llm.grammar import prompt_gbnf
    from demoforge.lib.llm.prompting import format_actions
    from tests.support.llm import gbnf_regex

    ex, p = _compact_prompt()
    g = gbnf_regex(prompt_gbnf(p, p.text))
    written = format_actions(COMPACT.encode_poses(np.array(ex[2][:4])), 0)
    assert g.fullmatch(written[len(p.answer_prefix):])
    assert not g.fullmatch(format_actions(ex[2][:4], 3)[len(p.answer_prefix):])  # metres with decimals: no
    assert "150" in written and not g.fullmatch(written.replace("150", "15000", 1)[len(p.answer_prefix):])


@pytest.mark.slow
def test_the_embedded_model_answers_a_compact_prompt_in_shape_under_the_grammar():
    pytest.importorskip("llama_cpp", reason="llama-cpp-python is not installed: scripts/setup_llm.sh")
    from demoforge.lib.llm import Sampling
    from demoforge.lib.llm.local_backend import LocalBackend
    from demoforge.lib.llm.prompting import parse_actions

    ex, p = _compact_prompt(n_waypoints=2)
    c = LocalBackend(n_ctx=4096).complete(p, Sampling(temperature=0.0, max_tokens=120, seed=0, stop=p.stop,
                                                      structured=True))
    res = parse_actions(c.text, expected_waypoints=2, prefix=p.answer_prefix)
    assert res.status == "ok" and res.actions.shape == (2, 2, 8), (res.status, c.text)
    assert "." not in c.text and c.finish_reason == "stop", c.text
