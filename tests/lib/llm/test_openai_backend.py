"""The OpenAI-compatible client (demoforge.lib.llm.openai_backend) against a real local HTTP server with
scripted answers (tests/support/fake_openai.py): usage, modes, retries, timeouts, caps, keys kept secret."""

from __future__ import annotations

import pickle

import pytest

from demoforge.lib.llm import (
    Completion, LLMBudgetExceeded, LLMError, LLMRequestError, LLMTimeoutError, Sampling, get_backend,
)
from demoforge.lib.llm.openai_backend import OpenAIBackend
from demoforge.lib.llm.prompting import parse_actions
from tests.support.fake_openai import SECRET, FakeOpenAIServer, openai_backend as backend, small_prompt


@pytest.fixture()
def server():
    s = FakeOpenAIServer()
    yield s
    s.close()


# ------------------------------------------------------------------------------------------------
# openai backend
# ------------------------------------------------------------------------------------------------

def test_openai_normal_answer_with_usage(server):
    answer = "```\n[[[0.1,0.2,0.3,0,0,0,1,1],[0.1,0.2,0.3,0,0,0,1,0]],[[0.1,0.2,0.3,0,0,0,1,0],[0,0,0,0,0,0,1,0]]]\n```"
    server.script = [("ok", answer, {"prompt_tokens": 123, "completion_tokens": 45, "total_tokens": 168})]
    b = backend(server)
    p = small_prompt()
    c = b.complete(p, Sampling(temperature=0.2, top_p=0.9, max_tokens=77, seed=5, stop=("\n#",)))
    assert isinstance(c, Completion)
    assert c.text == answer and c.prompt_tokens == 123 and c.completion_tokens == 45
    assert c.usage_source == "api" and c.finish_reason == "stop" and c.latency_s > 0 and not c.cached
    req = server.requests[0]
    assert req["path"] == "/v1/chat/completions"
    assert req["body"]["messages"] == list(p.messages)
    assert req["body"]["model"] == "test-model"
    assert req["body"]["max_tokens"] == 77 and req["body"]["seed"] == 5 and req["body"]["stop"] == ["\n#"]
    assert req["body"]["temperature"] == 0.2 and req["body"]["top_p"] == 0.9
    assert req["headers"]["Authorization"] == f"Bearer {SECRET}"
    assert parse_actions(c.text).status == "ok"
    assert b.requests_made == 1 and b.total_tokens_used == 168


def test_openai_completions_mode_and_missing_usage(server):
    server.script = [("ok", "0,0,0,0,0,0,1,1],[0,0,0,0,0,0,1,1]]]", None)]
    b = backend(server, mode="completions")
    p = small_prompt()
    c = b.complete(p, Sampling())
    assert server.requests[0]["path"] == "/v1/completions"
    assert server.requests[0]["body"]["prompt"] == p.text
    assert c.usage_source == "estimate" and c.prompt_tokens > 0 and c.completion_tokens > 0
    res = parse_actions(c.text)  # a completion continuing the "[[[" prefix, one waypoint
    assert res.status == "ok" and res.actions.shape == (1, 2, 8)


def test_openai_timeout_is_retried_then_fails_clearly(server):
    server.script = [("sleep", 1.0)]
    b = backend(server, timeout_s=0.25, max_retries=2)
    with pytest.raises(LLMTimeoutError) as ei:  # the server would answer after 1 s: only a timeout raises
        b.complete(small_prompt(), Sampling())
    msg = str(ei.value)
    assert "timeout" in msg and "3 attempts" in msg and SECRET not in msg
    assert len(server.requests) == 3 and b.requests_made == 3


def test_openai_500_then_success(server):
    server.script = [("status", 500, '{"error": "overloaded"}'), ("status", 503, "busy"),
                     ("ok", "[[[1]]]", {"prompt_tokens": 1, "completion_tokens": 1})]
    b = backend(server)
    c = b.complete(small_prompt(), Sampling())
    assert c.text == "[[[1]]]" and len(server.requests) == 3


def test_openai_429_is_retried(server):
    server.script = [("status", 429, '{"error": "rate limited"}'), ("ok", "done", None)]
    assert backend(server).complete(small_prompt(), Sampling()).text == "done"
    assert len(server.requests) == 2


def test_openai_400_not_retried_and_key_redacted(server):
    server.script = [("status", 400, '{"error": "bad request, you sent {auth}"}')]
    b = backend(server)
    with pytest.raises(LLMRequestError) as ei:
        b.complete(small_prompt(), Sampling())
    assert ei.value.status == 400 and len(server.requests) == 1
    assert "HTTP 400" in str(ei.value) and "bad request" in str(ei.value)
    assert SECRET not in str(ei.value) and SECRET not in repr(ei.value)


def test_openai_500_exhausted_key_redacted(server):
    server.script = [("status", 500, "internal error for {auth}")]
    with pytest.raises(LLMRequestError) as ei:
        backend(server, max_retries=1).complete(small_prompt(), Sampling())
    assert ei.value.status == 500 and len(server.requests) == 2
    assert SECRET not in str(ei.value) and "2 attempts" in str(ei.value)


def test_openai_connection_refused_is_clear():
    with pytest.raises(LLMRequestError) as ei:
        OpenAIBackend(model="m", base_url="http://127.0.0.1:9/v1", api_key=SECRET, max_retries=1,
                      backoff_s=0.01, timeout_s=2).complete(small_prompt(), Sampling())
    assert "connection failed" in str(ei.value) and SECRET not in str(ei.value)


def test_openai_request_cap(server):
    server.script = [("ok", "x", {"prompt_tokens": 1, "completion_tokens": 1})]
    b = backend(server, max_requests=2)
    b.complete(small_prompt(), Sampling())
    b.complete(small_prompt(), Sampling())
    with pytest.raises(LLMBudgetExceeded, match="request cap"):
        b.complete(small_prompt(), Sampling())
    assert len(server.requests) == 2


def test_openai_retries_count_against_request_cap(server):
    server.script = [("status", 500, "err")]
    b = backend(server, max_requests=2, max_retries=5)
    with pytest.raises(LLMBudgetExceeded):
        b.complete(small_prompt(), Sampling())
    assert len(server.requests) == 2


def test_openai_token_cap(server):
    server.script = [("ok", "x", {"prompt_tokens": 30, "completion_tokens": 10})]
    b = backend(server, max_total_tokens=50)
    b.complete(small_prompt(), Sampling())  # 40 used
    b.complete(small_prompt(), Sampling())  # 80 used: over the cap after this answer
    with pytest.raises(LLMBudgetExceeded, match="token cap"):
        b.complete(small_prompt(), Sampling())
    assert len(server.requests) == 2


def test_openai_config_from_environment(server, monkeypatch):
    monkeypatch.setenv("OPENAI_BASE_URL", server.url)
    monkeypatch.setenv("OPENAI_API_KEY", SECRET)
    monkeypatch.setenv("DEMOFORGE_LLM_MODEL", "env-model")
    b = get_backend("openai", backoff_s=0.01)
    assert b.model == "env-model"
    b.complete(small_prompt(), Sampling())
    assert server.requests[0]["headers"]["Authorization"] == f"Bearer {SECRET}"
    assert server.requests[0]["body"]["model"] == "env-model"
    # the key is in no repr and no pickle; unpickling re-reads it from the environment
    assert SECRET not in repr(b)
    blob = pickle.dumps(b)
    assert SECRET.encode() not in blob
    assert pickle.loads(blob)._api_key == SECRET
    monkeypatch.delenv("DEMOFORGE_LLM_MODEL")
    with pytest.raises(LLMError, match="DEMOFORGE_LLM_MODEL"):
        get_backend("openai")
