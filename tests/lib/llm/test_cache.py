"""The LLM answer cache (demoforge.lib.llm.cache): a second call served from disk, keys without the API key,
a corrupt file a miss; against the scripted OpenAI-compatible server (tests/support/fake_openai.py)."""

from __future__ import annotations

import json

import pytest

from demoforge.lib.llm import Sampling
from demoforge.lib.llm.cache import CachedBackend
from tests.support.fake_openai import SECRET, FakeOpenAIServer, openai_backend as backend, small_prompt


@pytest.fixture()
def server():
    s = FakeOpenAIServer()
    yield s
    s.close()


def test_cache_serves_second_call_from_disk(server, tmp_path):
    server.script = [("ok", "[[[0,0,0,0,0,0,1,1],[0,0,0,0,0,0,1,1]]]", {"prompt_tokens": 10, "completion_tokens": 5})]
    cached = CachedBackend(backend(server), tmp_path / "llm_cache")
    p, s = small_prompt(), Sampling(seed=1)
    c1 = cached.complete(p, s)
    c2 = cached.complete(p, s)
    assert len(server.requests) == 1
    assert not c1.cached and c2.cached
    assert (c2.text, c2.prompt_tokens, c2.completion_tokens, c2.finish_reason, c2.latency_s) == \
        (c1.text, c1.prompt_tokens, c1.completion_tokens, c1.finish_reason, c1.latency_s)
    # a fresh wrapper (new process) reads the same file
    again = CachedBackend(backend(server), tmp_path / "llm_cache")
    assert again.complete(p, s).cached and len(server.requests) == 1
    # different sampling / prompt -> different key -> a new request
    cached.complete(p, Sampling(seed=2))
    cached.complete(p, Sampling(seed=1, temperature=0.7))
    cached.complete(small_prompt(shift=0.1), s)
    assert len(server.requests) == 4
    files = sorted((tmp_path / "llm_cache").rglob("*.json"))
    assert len(files) == 4 and not list((tmp_path / "llm_cache").rglob(".tmp-*"))
    for f in files:
        text = f.read_text()
        assert SECRET not in text
        rec = json.loads(text)
        assert rec["key"] == f.stem and rec["completion"]["text"]
    assert cached.hits == 1 and cached.misses == 4


def test_cache_key_ignores_api_key_and_survives_corruption(server, tmp_path):
    p, s = small_prompt(), Sampling()
    c_a = CachedBackend(backend(server, api_key="key-A"), tmp_path)
    c_b = CachedBackend(backend(server, api_key="key-B"), tmp_path)
    assert c_a.path_for(p, s) == c_b.path_for(p, s)
    c_a.complete(p, s)
    c_a.path_for(p, s).write_text("{not json")
    assert not c_a.complete(p, s).cached  # corrupt file = miss, rewritten
    assert c_a.complete(p, s).cached
    # other models / backends get other keys
    assert c_a.path_for(p, s) != CachedBackend(backend(server, model="other"), tmp_path).path_for(p, s)
