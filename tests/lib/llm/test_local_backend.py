"""The embedded backend (demoforge.lib.llm.local_backend): the real Gemma 3 270M GGUF via llama.cpp generating a
real answer, its KV cache, and a runtime built without AMX kernels."""

from __future__ import annotations

import importlib.util
import time

import pytest

from demoforge.lib.llm import Sampling, get_backend
from demoforge.lib.llm.cache import CachedBackend
from demoforge.lib.llm.prompting import PARSE_STATUSES, count_tokens, parse_actions
from tests.support.fake_openai import small_prompt

_HAVE_LLAMA = importlib.util.find_spec("llama_cpp") is not None


@pytest.mark.skipif(not _HAVE_LLAMA, reason="llama_cpp (llama-cpp-python) is not importable: "
                    "install requirements/llm.txt (scripts/setup_llm.sh)")
def test_the_embedded_runtime_has_no_amx_kernels():
    """scripts/setup_llm.sh builds llama.cpp without Intel AMX: its AMX matrix kernels crash the first
    decode of the Q4_K_M model on Sapphire Rapids CPUs (a segfault of the whole test worker)."""
    import llama_cpp
    from pathlib import Path

    libs = [p for p in (Path(llama_cpp.__file__).parent / "lib").glob("libggml-cpu.so*") if p.is_file()]
    assert libs, "llama_cpp ships no libggml-cpu.so"
    with_amx = [p.name for p in libs if b"ggml_backend_amx_mul_mat" in p.read_bytes()]
    assert not with_amx, f"{with_amx} built with AMX kernels: run `bash scripts/setup_llm.sh` to rebuild"


@pytest.mark.slow
@pytest.mark.skipif(not _HAVE_LLAMA, reason="llama_cpp (llama-cpp-python) is not importable: "
                    "install requirements/llm.txt (scripts/setup_llm.sh)")
def test_local_backend_generates_a_real_answer(tmp_path):
    from demoforge.lib.llm.local_backend import LocalBackend, ensure_gguf

    path = ensure_gguf()
    assert path.exists() and path.stat().st_size > 200e6
    b = get_backend("local")
    assert isinstance(b, LocalBackend)
    p = small_prompt(n_examples=1)
    s = Sampling(temperature=0.0, max_tokens=48, seed=0, stop=p.stop)
    t0 = time.perf_counter()
    c = b.complete(p, s)
    dt = time.perf_counter() - t0
    assert c.text.strip(), "the model produced nothing"
    assert 0 < c.completion_tokens <= 48
    # real token counts from Gemma's tokenizer: prompt = tokens(text) + BOS
    assert c.prompt_tokens == b.count_tokens(p.text) + 1
    assert count_tokens(p.text, b) == b.count_tokens(p.text) != 0
    assert c.usage_source == "tokenizer" and c.model == "gemma-3-270m-q4_k_m"
    assert get_backend("local").llm is b.llm  # the model stays loaded
    res = parse_actions(c.text)
    print(f"\nlocal gemma: load {b.load_time_s:.2f}s, {c.prompt_tokens} prompt tok, {c.completion_tokens} "
          f"completion tok in {dt:.2f}s; parse: {res.status} {res.detail}\n{c.text!r}")
    # what the 270M base model answers is not this backend's contract (any parse status can come back;
    # the parser has its own tests): only that an answer is parsed without raising, into a known status
    assert res.status in PARSE_STATUSES and (res.status != "ok" or res.actions.shape[1:] == (2, 8))
    # through the cache wrapper: the first call asks the model again (same seed, same answer), the
    # second is served from disk
    cb = CachedBackend(b, tmp_path)
    first = cb.complete(p, s)
    assert not first.cached and first.text == c.text
    assert cb.complete(p, s).cached


@pytest.mark.slow
@pytest.mark.skipif(not _HAVE_LLAMA, reason="llama_cpp (llama-cpp-python) is not importable: "
                    "install requirements/llm.txt (scripts/setup_llm.sh)")
def test_local_windowed_cache_answer_does_not_depend_on_the_previous_prompt():
    """Gemma's sliding-window layers keep only the last window (+ one micro-batch) of the KV cache by
    default. llama-cpp-python would resume a prompt from the previous call's shared prefix even when
    that call went on more than a window past it (a long answer, or here a long prompt: the same cache
    state, reached by prefill instead of 700 decoding steps), so the prefix's window is gone; the
    backend must answer exactly as on an empty cache. n_batch=64 keeps the window cache small
    (512 + 64), so 700 tokens past the shared prefix are enough."""
    from demoforge.lib.llm.local_backend import LocalBackend

    b = LocalBackend(n_ctx=4096, n_batch=64)
    assert not b.swa_full and b.cache_identity()["kv"] == "swa-window"
    first = small_prompt(n_examples=1).text
    follow_up = first + "0.1"  # shares the whole first prompt as its prefix
    short = Sampling(temperature=0.0, max_tokens=24, seed=0, stop=())
    reference = b.complete(follow_up, short)
    went_on = first + " 0.25" * 175
    assert b.count_tokens(went_on) - b.count_tokens(first) >= 512 + 64 + 100
    assert b.complete(went_on, Sampling(temperature=0.0, max_tokens=1, seed=0, stop=())).completion_tokens == 1
    assert b.complete(follow_up, short).text == reference.text
