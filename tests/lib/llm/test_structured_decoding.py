"""The fast greedy structured decoder: its automaton accepts exactly the GBNF grammar's language, and
on the real embedded model its answers are the grammar sampler's, token for token."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from demoforge.lib.llm import Sampling
from demoforge.lib.llm.grammar import actions_gbnf, longest_answer_chars
from demoforge.lib.llm.prompting import build_prompt, parse_actions
from demoforge.lib.llm.structured_decoding import ActionListLanguage
from tests.support.llm import demo, gbnf_regex, needs_llama, real_prompts


@st.composite
def near_words(draw):
    """A grammar's parameters and a string near its language: a word of the language, half of the time
    with one defect at a boundary (a digit or a decimal too many, a bad gripper state, one row too many
    or too few, a stray newline, one character inserted, deleted or replaced)."""
    precision = draw(st.integers(0, 3))
    int_digits = draw(st.sampled_from([2, 4]))
    fixed = draw(st.booleans())
    n = draw(st.integers(1, 3))
    lo, hi = (n, n) if fixed else (1, 4)
    prefix = draw(st.sampled_from(["", "[", "[[", "[[["]))
    defect = draw(st.sampled_from(["none"] * 7 + ["int_digit", "decimal", "grip", "rows", "newline", "edit",
                                                  "zero_quat", "near_zero_quat"]))
    rows = draw(st.integers(lo, hi))
    if defect == "rows":
        rows = draw(st.sampled_from([r for r in (lo - 1, hi + 1) if r >= 1]))
    digits = st.sampled_from("0123456789")

    def number() -> str:
        s = draw(st.sampled_from(["", "-"])) + "".join(draw(st.lists(digits, min_size=1, max_size=int_digits)))
        if precision and draw(st.booleans()):
            s += "." + "".join(draw(st.lists(digits, min_size=1, max_size=precision)))
        return s

    values = [[[number() for _ in range(7)] + [draw(st.sampled_from("01"))] for _ in range(2)] for _ in range(rows)]
    r, a, f = draw(st.integers(0, rows - 1)), draw(st.integers(0, 1)), draw(st.integers(0, 6))
    if defect == "int_digit":
        whole = values[r][a][f].split(".")
        values[r][a][f] = ".".join([whole[0].lstrip("-").rjust(int_digits + 1, "7")] + whole[1:])
    elif defect == "decimal":
        values[r][a][f] = values[r][a][f].split(".")[0] + "." + "5" * (precision + 1)
    elif defect in ("zero_quat", "near_zero_quat"):  # four zeros (no rotation), or one digit short of it
        zeros = [draw(st.sampled_from(["0", "-0", "00"][: 1 + int_digits // 2] + (["0.0", "-0." + "0" * precision]
                                                                                  if precision else [])))
                 for _ in range(4)]
        if defect == "near_zero_quat" and precision:
            zeros[draw(st.integers(0, 3))] = "0." + "0" * (precision - 1) + "1"
        values[r][a][3:7] = zeros
    elif defect == "grip":
        values[r][a][7] = draw(st.sampled_from(["2", "01", "0.5", "-1"]))
    seps = [draw(st.sampled_from(["", "\n"])) for _ in range(rows)]
    text = "[[[" + "],[".join(",".join(v) for v in values[0]) + "]]"
    for k in range(1, rows):
        text += "," + seps[k] + "[[" + "],[".join(",".join(v) for v in values[k]) + "]]"
    text += "]"
    if defect == "newline":  # a newline where the grammar has none: inside an arm, or a second one
        text = draw(st.sampled_from([text.replace(",", ",\n", 1), text.replace("]],", "]],\n\n", 1)]))
    if defect == "edit":
        i = draw(st.integers(3, len(text) - 1))
        c = draw(st.sampled_from(list("0123456789-.,[]\n")))
        text = draw(st.sampled_from([text[:i] + c + text[i:], text[:i] + text[i + 1:], text[:i] + c + text[i + 1:]]))
    return (n if fixed else None), precision, int_digits, prefix, text[len(prefix):]


_LIVE: dict[tuple, bool] = {}
_TRY = "1,]\n[0-."


def _can_finish(lang: ActionListLanguage, state: tuple) -> bool:
    """Whether some continuation of ``state`` is accepted: a depth-first search that tries a non-zero
    digit and the separators first (the shortest way on), remembering every verdict. "1" and "0" stand
    for every digit: the automaton tells digits apart only as zero or not."""
    stack, path, seen = [(state, iter(_TRY))], [state], {state}
    while stack:
        s, chars = stack[-1]
        key = (lang, s)
        if lang.accepting(s) or _LIVE.get(key):
            for p in path:
                _LIVE[(lang, p)] = True
            return True
        for ch in chars:
            t = lang.advance(s, ch)
            if t is not None and t not in seen and _LIVE.get((lang, t)) is not False:
                seen.add(t)
                stack.append((t, iter(_TRY)))
                path.append(t)
                break
        else:
            _LIVE[key] = False
            stack.pop()
            path.pop()
    return False


def test_no_dead_end_after_three_zero_quaternion_components():
    # compact numbers (4 integer digits, no decimals): "0000" as the last component would leave no way on
    lang = ActionListLanguage(1, 1, 0, "", 4)
    s = lang.advance(lang.start(), "[[[1,2,3,0,0,0,000")
    assert s is not None and lang.advance(s, "0") is None and lang.advance(s, "7") is not None
    thesis = ActionListLanguage(1, 1, 3, "", 2)
    s = thesis.advance(thesis.start(), "[[[0.1,0.2,0.3,0,0.0,-0,00.00")
    assert thesis.advance(s, "0") is None and thesis.advance(s, "1") is not None


@settings(max_examples=400, deadline=None)
@given(near_words())
def test_the_automaton_accepts_exactly_the_gbnf_grammars_words(case):
    n, precision, int_digits, prefix, text = case
    grammar = gbnf_regex(actions_gbnf(n, precision, prefix, 4, int_digits))
    lo, hi = (n, n) if n is not None else (1, 4)
    lang = ActionListLanguage(lo, hi, precision, prefix, int_digits)
    state = lang.advance(lang.start(), text)
    assert lang.accepting(state) == bool(grammar.fullmatch(text)), text
    s = lang.start()  # every state the automaton reaches can still end in a word (the decoder never strands itself)
    for ch in text:
        s = lang.advance(s, ch)
        if s is None:
            break
        assert _can_finish(lang, s), (text, s)
    if lang.accepting(state):  # every prefix of a word is a live state
        s = lang.start()
        for ch in text:
            s = lang.advance(s, ch)
            assert s is not None
        assert lang.advance(state, "]") is None and lang.advance(state, "\n") is None  # nothing after the end


def test_the_automaton_reads_a_prompts_own_example_and_rejects_its_neighbours():
    from demoforge.lib.llm.prompting import format_actions

    text = format_actions(demo(n=4)[2], 3)
    lang = ActionListLanguage(4, 4, 3, "", 2)
    assert lang.accepting(lang.advance(lang.start(), text))
    assert not lang.accepting(lang.advance(lang.start(), format_actions(demo(n=5)[2], 3)))
    assert lang.advance(lang.start(), text.replace("],[", ",1],[", 1)) is None  # a ninth number
    rows = text[3:-3].split("]],\n[[")
    assert len(rows) == 4
    three = "[[[" + "]],\n[[".join(rows[:3]) + "]]]"
    assert not lang.accepting(lang.advance(lang.start(), three))  # one waypoint too few
    assert lang.accepting(lang.advance(lang.start(), text.replace("]],\n[[", "]],[[")))  # the newline is optional
    assert lang.advance(lang.start(), text.replace("]],\n[[", "]],\n\n[[", 1)) is None  # one newline at most
    free = ActionListLanguage(1, 4, 3, "", 2)
    assert free.accepting(free.advance(free.start(), three)) and free.accepting(free.advance(free.start(), text))
    with pytest.raises(ValueError):
        ActionListLanguage(3, 2)
    with pytest.raises(ValueError):
        ActionListLanguage(1, 1, prefix="x")


@pytest.mark.slow
@needs_llama
def test_fast_answers_equal_the_grammar_samplers_token_for_token():
    from demoforge.lib.llm.local_backend import LocalBackend

    fast, gbnf = LocalBackend(n_ctx=4096), LocalBackend(n_ctx=4096, structured_decoder="gbnf")
    a = demo(0.0, seed=3)
    # llama.cpp's grammar sampler costs about 60 ms a token here. The thesis-format answer has room for the
    # grammar's longest answer, so it ends on its own; the other two are cut, each after a whole row
    # (eight numbers), where llama.cpp cuts
    _, _, ends = real_prompts()
    prompts = [ends,
               build_prompt([a], a[0] + 0.01, a[1], n_waypoints=2, number_format="compact"),  # integers, 4 digits
               build_prompt([a], a[0] - 0.01, a[1])]  # keyframes: the row count is not fixed (1..64)
    reasons, answers = [], []
    for p, max_tokens in zip(prompts, [longest_answer_chars(2, ends.precision, ends.answer_prefix), 60, 40]):
        s = Sampling(temperature=0.0, max_tokens=max_tokens, seed=0, stop=p.stop, structured=True)
        want, got = gbnf.complete(p, s), fast.complete(p, s)
        answers.append(got.text)
        assert got.text == want.text, (p.number_format, got.text, want.text)
        assert (got.completion_tokens, got.prompt_tokens, got.finish_reason) == \
            (want.completion_tokens, want.prompt_tokens, want.finish_reason)
        reasons.append(want.finish_reason)
    assert reasons == ["stop", "length", "length"]  # a natural end, and cut where llama.cpp cuts
    # the answer that ended on its own parses into its waypoints (test_llm_grammar: the other real prompts)
    res = parse_actions(answers[0], expected_waypoints=ends.n_waypoints, prefix=ends.answer_prefix)
    assert res.status == "ok" and res.actions.shape == (ends.n_waypoints, 2, 8) and res.detail == "", answers[0]
    with pytest.raises(ValueError):
        LocalBackend(structured_decoder="regex")
