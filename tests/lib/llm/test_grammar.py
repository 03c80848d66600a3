"""Structured output (lib/llm/grammar.py): the GBNF grammar, the JSON schema, the cache key, and the
embedded model's constrained answers (always (n, 2, 8)). (The commands' flags for it: tests/cli/test_evaluation.py
and test_pipeline.py; llm_predict's default: tests/tasks/test_llm_eval.py.)"""

from __future__ import annotations

import json

import numpy as np
import pytest

from demoforge.lib.llm import FakeBackend, Sampling
from demoforge.lib.llm.cache import cache_key
from demoforge.lib.llm.grammar import (
    MAX_ROWS, actions_gbnf, actions_json_schema, longest_answer_chars, opened_prefix, response_format,
)
from demoforge.lib.llm.prompting import format_actions, parse_actions
from tests.support.llm import demo, gbnf_regex, needs_llama, real_prompts


# ------------------------------------------------------------------------------------------------
# the grammar text and the JSON schema (no model)
# ------------------------------------------------------------------------------------------------

def test_grammar_counts_exactly_n_waypoints_and_matches_the_prompt_format():
    g = gbnf_regex(actions_gbnf(4, precision=3))
    # what the prompt shows for an example is a word of the grammar's language; other counts are not
    text = format_actions(demo(n=4)[2], 3)
    assert g.fullmatch(text)
    assert not g.fullmatch(format_actions(demo(n=5)[2], 3)) and not g.fullmatch(format_actions(demo(n=3)[2], 3))
    bad = text.replace("],[", ",1],[", 1)  # a ninth number in the first arm
    assert not g.fullmatch(bad) and not g.fullmatch(text.replace(",1]", ",0.5]", 1))  # gripper 0/1 only
    assert not g.fullmatch(text.replace("0.15", "0.15001", 1)) and not g.fullmatch(text.replace("0.15", "100.15", 1))
    # continuing after the prompt's opened "[[[": the grammar starts inside the first arm
    assert gbnf_regex(actions_gbnf(4, prefix="[[[")).fullmatch(text[3:])
    assert gbnf_regex(actions_gbnf(None)).fullmatch(text)
    assert opened_prefix("Action Sequence:\n[[[") == "[[[" and opened_prefix("x") == ""
    assert "more{0,63}" in actions_gbnf(None) and MAX_ROWS == 64
    assert "more" not in actions_gbnf(1).splitlines()[0]
    # a quaternion of four zeros (the parser's zero_quaternion) is refused in either arm; one non-zero digit passes
    first_quat = ",".join(text[3:].split("]")[0].split(",")[3:7])
    assert not g.fullmatch(text.replace(first_quat, "0,-0.0,00,0.000", 1))
    assert g.fullmatch(text.replace(first_quat, "0,-0.0,00,0.001", 1))
    assert gbnf_regex(actions_gbnf(4, precision=0, int_digits=4)).fullmatch(
        "[[[" + "]],\n[[".join(["1,2,3,0,0,0,7,1],[4,5,6,0,0,0,-1,0"] * 4) + "]]]")
    assert not gbnf_regex(actions_gbnf(4, precision=0, int_digits=4)).fullmatch(
        "[[[" + "]],\n[[".join(["1,2,3,0,0,0,7,1],[4,5,6,0,0,0,0000,0"] * 4) + "]]]")
    with pytest.raises(ValueError):
        actions_gbnf(0)
    with pytest.raises(ValueError):
        actions_gbnf(2, prefix="x")


@pytest.mark.parametrize("n, precision, int_digits, prefix", [(1, 3, 2, ""), (3, 3, 2, "[[["), (2, 0, 4, "[")])
def test_longest_answer_chars_is_the_length_of_the_grammars_longest_word(n, precision, int_digits, prefix):
    g = gbnf_regex(actions_gbnf(n, precision, prefix, int_digits=int_digits))
    num = "-" + "9" * int_digits + ("." + "9" * precision if precision else "")
    arm = ",".join([num] * 7 + ["1"])
    longest = ("[[[" + ("]],\n[[".join([arm + "],[" + arm] * n)) + "]]]")[len(prefix):]
    assert g.fullmatch(longest) and len(longest) == longest_answer_chars(n, precision, prefix, int_digits)
    # one digit more anywhere is outside the language
    assert not g.fullmatch(longest.replace(num, num[:2] + "9" + num[2:], 1))


def test_json_schema_fixes_the_shape_and_parse_actions_reads_its_answers():
    s = actions_json_schema(3)
    a = s["properties"]["actions"]
    assert (a["minItems"], a["maxItems"]) == (3, 3)
    assert (a["items"]["minItems"], a["items"]["maxItems"]) == (2, 2)
    assert (a["items"]["items"]["minItems"], a["items"]["items"]["maxItems"]) == (8, 8)
    assert s["required"] == ["actions"] and s["additionalProperties"] is False
    assert (actions_json_schema(None)["properties"]["actions"]["minItems"],
            actions_json_schema(None)["properties"]["actions"]["maxItems"]) == (1, MAX_ROWS)
    rf = response_format(3)
    assert rf["type"] == "json_schema" and rf["json_schema"]["schema"] == s
    # a JSON answer of that schema parses with the tolerant parser as it is (no reader of its own)
    acts = demo(n=3)[2]
    res = parse_actions(json.dumps({"actions": acts.tolist()}), expected_waypoints=3, prefix="[[[")
    assert res.status == "ok" and res.actions.shape == (3, 2, 8) and res.detail == ""
    assert np.allclose(res.actions[..., :3], acts[..., :3])


def test_structured_is_part_of_the_cache_key(monkeypatch):
    b = FakeBackend(["x"])
    p = real_prompts()[0]
    free, structured = Sampling(), Sampling(structured=True)
    assert cache_key(b, p, free) != cache_key(b, p, structured)
    assert cache_key(b, p, structured) == cache_key(b, p, Sampling(structured=True))
    assert Sampling().structured is False and structured.to_dict()["structured"] is True
    # a new grammar version is a new key for structured answers only (an old answer may break the new rule)
    import demoforge.lib.llm.cache as cache_module

    before = cache_key(b, p, structured), cache_key(b, p, free)
    monkeypatch.setattr(cache_module, "GRAMMAR_VERSION", cache_module.GRAMMAR_VERSION + 1)
    assert cache_key(b, p, structured) != before[0] and cache_key(b, p, free) == before[1]


# ------------------------------------------------------------------------------------------------
# the real embedded model
# ------------------------------------------------------------------------------------------------

@needs_llama
def test_gbnf_grammar_compiles_in_llama_cpp():
    """LlamaGrammar.from_string only stores the text; llama.cpp parses it when the sampler is built,
    and a bad grammar makes llama_sampler_init_grammar return NULL."""
    import llama_cpp
    from demoforge.lib.llm.local_backend import LocalBackend

    vocab = llama_cpp.llama_model_get_vocab(LocalBackend(n_ctx=4096).llm.model)
    for n, prefix in ((2, "[[["), (3, ""), (None, "[[[")):
        s = llama_cpp.llama_sampler_init_grammar(vocab, actions_gbnf(n, 3, prefix).encode(), b"root")
        assert s, f"llama.cpp rejected the grammar for n={n}, prefix={prefix!r}"
        llama_cpp.llama_sampler_free(s)
    assert not llama_cpp.llama_sampler_init_grammar(vocab, b'root ::= "a" (', b"root")  # the check can fail


@pytest.mark.slow
@needs_llama
def test_structured_greedy_answers_of_the_embedded_model_always_parse():
    from demoforge.lib.llm.local_backend import LocalBackend

    b = LocalBackend(n_ctx=4096)
    # the third real prompt's structured answer is checked the same way in test_structured_decoding
    # (test_fast_answers_equal_the_grammar_samplers_token_for_token), where it is decoded anyway
    for p in real_prompts()[:2]:
        n = p.n_waypoints
        # room for the longest answer the grammar admits: a shorter budget makes "always parses" depend
        # on how many decimals the model happens to write (it wrote 3 on one CPU, 1-2 on another)
        budget = longest_answer_chars(n, p.precision, p.answer_prefix)
        c = b.complete(p, Sampling(temperature=0.0, max_tokens=budget, seed=0, stop=p.stop, structured=True))
        res = parse_actions(c.text, expected_waypoints=n, prefix=p.answer_prefix)
        assert res.status == "ok" and res.actions.shape == (n, 2, 8), (res.status, res.detail, c.text)
        assert c.finish_reason == "stop", c.text  # the grammar closed the list; nothing ran into max_tokens
        assert res.detail == ""
