"""The reduced-vocabulary model of the fast structured decoder (demoforge.lib.llm.reduced_vocab): the same
logits for the tokens it keeps, the same answers token for token, the full model for a prompt it cannot
read, and a GGUF copy built once and checked before use."""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import shutil

import numpy as np
import pytest

from demoforge.lib.llm import Sampling
from demoforge.lib.llm.prompting import build_prompt
from tests.support.llm import demo, needs_llama

pytestmark = [pytest.mark.slow, needs_llama,
              pytest.mark.skipif(importlib.util.find_spec("gguf") is None,
                                 reason="the gguf package (requirements/llm.txt) is not installed")]

N_CTX = 4096


@pytest.fixture(scope="module")
def models():
    from demoforge.lib.llm.local_backend import LocalBackend

    backend = LocalBackend(n_ctx=N_CTX)
    reduced = backend.reduced_model()
    assert reduced is not None
    return backend, reduced


def prompts():
    """One example of 12 steps written as 8 uniform waypoints (thesis and compact numbers), and as
    keyframes (the row count not fixed). The answers' equality does not depend on the example's length;
    a short one keeps each prompt near 1,200 tokens (its prefill is most of the test's time)."""
    ex, q = demo(0.0, n=12, seed=0), demo(0.01, n=12, seed=5)
    return [build_prompt([ex], q[0], q[1], n_waypoints=8),
            build_prompt([ex], q[0], q[1], n_waypoints=8, number_format="compact"),
            build_prompt([ex], q[0], q[1])]


def _lang(p, text=None):
    from demoforge.lib.llm.grammar import MAX_ROWS
    from demoforge.lib.llm.structured_decoding import language_for_prompt

    return language_for_prompt(p, text or p.text, MAX_ROWS)


def _tokens(llm, text):
    return llm.tokenize(text.encode("utf-8"), add_bos=True, special=True)


def test_the_reduced_model_keeps_the_action_tokens_and_gives_their_logits_bit_for_bit(models):
    from demoforge.lib.llm.structured_decoding import action_tokens

    backend, reduced = models
    full = backend.llm
    ids, texts = action_tokens(full)
    assert np.isin(ids, reduced.ids).all()
    assert reduced.llm.n_vocab() == len(reduced.ids) < full.n_vocab() // 100 and len(reduced.ids) % 64 == 0
    assert action_tokens(reduced.llm)[1] == texts  # the same pieces, in the same (id) order
    tokens = _tokens(full, prompts()[2].text)
    for llm, toks in ((full, tokens), (reduced.llm, reduced.map_prompt(tokens))):
        llm.reset()
        llm.eval(toks)
    lf = np.ctypeslib.as_array(full._ctx.get_logits_ith(-1), shape=(full.n_vocab(),))
    lr = np.ctypeslib.as_array(reduced.llm._ctx.get_logits_ith(-1), shape=(reduced.llm.n_vocab(),))
    np.testing.assert_array_equal(lr, lf[reduced.ids])


def test_reduced_answers_equal_the_full_models_token_for_token(models):
    from demoforge.lib.llm.reduced_vocab import decode
    from demoforge.lib.llm.structured_decoding import greedy_structured

    backend, reduced = models
    full = backend.llm
    # the keyframe prompt's answer is compared through the backend (next test)
    for p, max_tokens in zip(prompts()[:2], (80, 80)):
        tokens = _tokens(full, p.text)
        want = greedy_structured(full, tokens, _lang(p), max_tokens)
        got, used = decode(full, reduced, tokens, _lang(p), max_tokens)
        assert used, p.number_format
        assert got == want, (p.number_format, got.text, want.text)
        assert len(got.tokens) > 60 and got.prompt_tokens == len(tokens)


def test_the_backends_fast_decoder_uses_the_reduced_model_and_answers_as_fast_full(models, monkeypatch):
    from demoforge.lib.llm import reduced_vocab
    from demoforge.lib.llm.local_backend import LocalBackend

    backend, _ = models
    used = []
    real = reduced_vocab.decode
    monkeypatch.setattr(reduced_vocab, "decode", lambda *a, **k: used.append(real(*a, **k)[1]) or real(*a, **k))
    p = prompts()[2]
    s = Sampling(temperature=0.0, max_tokens=60, seed=0, stop=p.stop, structured=True)
    got = backend.complete(p, s)
    want = LocalBackend(n_ctx=N_CTX, structured_decoder="fast-full").complete(p, s)
    assert used == [True, False]  # "fast" on the reduced model, "fast-full" on the full one
    assert (got.text, got.completion_tokens, got.prompt_tokens, got.finish_reason) == \
        (want.text, want.completion_tokens, want.prompt_tokens, want.finish_reason)
    assert got.completion_tokens == 60 and got.finish_reason == "length" and got.text.count(",") > 10
    assert backend.cache_identity() == LocalBackend(structured_decoder="fast-full").cache_identity()


def test_a_prompt_with_a_token_outside_the_reduced_vocabulary_is_answered_by_the_full_model(models, monkeypatch):
    from demoforge.lib.llm import reduced_vocab

    backend, reduced = models
    full = backend.llm
    p = prompts()[2]
    text = p.text.replace("** New Input **", "** New Input (xylophone) **")
    assert reduced.map_prompt(_tokens(full, text)) is None
    answered = []
    real = reduced_vocab.decode
    monkeypatch.setattr(reduced_vocab, "decode", lambda *a, **k: answered.append(real(*a, **k)) or answered[-1])
    s = Sampling(temperature=0.0, max_tokens=50, seed=0, stop=p.stop, structured=True)
    got = backend.complete(dataclasses.replace(p, text=text), s)
    (result, used), = answered
    assert not used  # the full model answered (its greedy structured answer, as decode's fallback is)
    assert got.text == result.text and got.completion_tokens == 50 and got.text.count(",") > 10


def test_the_reduced_gguf_is_built_once_and_a_damaged_copy_is_rebuilt(models, tmp_path, monkeypatch):
    from demoforge.lib.llm import reduced_vocab
    from demoforge.lib.llm.local_backend import ensure_gguf

    _, reduced = models
    src = ensure_gguf(None)
    monkeypatch.setattr(reduced_vocab, "_VERIFIED", set())  # check the files on disk, not this process's memo
    before = os.stat(reduced.path)
    assert reduced_vocab.reduced_gguf(src, reduced.ids) == reduced.path
    after = os.stat(reduced.path)
    assert (after.st_ino, after.st_mtime_ns, after.st_size) == (before.st_ino, before.st_mtime_ns, before.st_size)

    # a copy beside a link to the original: reused while intact, rebuilt once damaged
    (tmp_path / src.name).symlink_to(src)
    target = tmp_path / reduced.path.name
    side = reduced.path.with_name(reduced.path.name + ".sha256")
    shutil.copy(reduced.path, target)
    shutil.copy(side, tmp_path / side.name)
    builds = []

    def build(s, ids, t):
        builds.append(t)
        shutil.copy(reduced.path, t)
        shutil.copy(side, t.with_name(side.name))

    monkeypatch.setattr(reduced_vocab, "_build", build)
    assert reduced_vocab.reduced_gguf(tmp_path / src.name, reduced.ids) == target and builds == []
    reduced_vocab._VERIFIED.clear()
    with open(target, "r+b") as f:  # truncated, as by an interrupted copy
        f.truncate(target.stat().st_size // 2)
    assert reduced_vocab.reduced_gguf(tmp_path / src.name, reduced.ids) == target and builds == [target]
    assert target.read_bytes() == reduced.path.read_bytes()
    reduced_vocab._VERIFIED.clear()
    (tmp_path / side.name).unlink()  # no checksum: not trusted either
    assert reduced_vocab.reduced_gguf(tmp_path / src.name, reduced.ids) == target and len(builds) == 2

    # a build that does not produce the file its checksum names is reported, not used
    reduced_vocab._VERIFIED.clear()
    with open(target, "r+b") as f:
        f.seek(1 << 20)
        f.write(b"\xff" * 64)
    monkeypatch.setattr(reduced_vocab, "_build", lambda s, ids, t: None)
    with pytest.raises(OSError, match="checksum"):
        reduced_vocab.reduced_gguf(tmp_path / src.name, reduced.ids)
