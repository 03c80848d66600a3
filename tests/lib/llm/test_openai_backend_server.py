"""The openai backend against a real OpenAI-compatible server: llama-cpp-python's own
(`python -m llama_cpp.server`, the session's ``llama_server`` fixture of tests/conftest.py) serving the
embedded Gemma 3 270M GGUF on a loopback port, `demoforge llm-eval --backend openai` end to end against
it, and the error paths (dead port, timeout, HTTP 500) through the llm-eval trial code.

Apples to apples with the local backend: the server has no chat template for this base GGUF (it
falls back to llama-2's), so the comparison uses the completions endpoint on ``prompt.text`` — the
text LocalBackend completes.  Two server defaults differ from LocalBackend's and are matched: the
request's ``repeat_penalty`` (the server's default is 1.1, ``create_completion``'s 1.0: sent as
1.0) and the KV cache (the server builds ``Llama`` with llama.cpp's default ``swa_full=True``;
LocalBackend defaults to the windowed cache, whose greedy answers differ in the last bits: the local
side uses ``swa_full=True``)."""

from __future__ import annotations

import http.server
import importlib.util
import socket
import threading
import time

import numpy as np
import pytest

from demoforge.lib.llm import LLMError, LLMRequestError, LLMTimeoutError, Sampling
from demoforge.lib.llm.openai_backend import OpenAIBackend
from demoforge.lib.llm.prompting import parse_actions
from demoforge.tasks.llm_eval import llm_predict
from tests.support.llm import demo, real_prompts

_HAVE_SERVER = all(importlib.util.find_spec(m) is not None
                   for m in ("llama_cpp", "uvicorn", "fastapi", "sse_starlette", "starlette_context",
                             "pydantic_settings"))
pytestmark = pytest.mark.skipif(not _HAVE_SERVER, reason="llama_cpp.server needs llama-cpp-python and "
                                "sse-starlette / starlette-context (pip install -r requirements/llm.txt)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def server_backend(base_url, model, **kw) -> OpenAIBackend:
    opts = dict(model=model, base_url=base_url, api_key="", mode="completions", timeout_s=120, max_retries=0,
                extra_body={"repeat_penalty": 1.0})
    opts.update(kw)
    return OpenAIBackend(**opts)


def test_server_greedy_answer_equals_the_local_backend(llama_server):
    from demoforge.lib.llm.local_backend import LocalBackend

    base, model = llama_server
    p = real_prompts()[0]
    s = Sampling(temperature=0.0, max_tokens=24, seed=0, stop=p.stop)
    remote = server_backend(base, model).complete(p, s)
    local = LocalBackend(n_ctx=4096, swa_full=True).complete(p, s)
    assert remote.text.strip() and remote.usage_source == "api"
    assert remote.text == local.text
    assert (remote.prompt_tokens, remote.completion_tokens) == (local.prompt_tokens, local.completion_tokens)


def test_structured_answer_through_the_server_parses(llama_server):
    base, model = llama_server
    p = real_prompts()[0]
    b = server_backend(base, model)
    # max_tokens is ample: the grammar ends the answer (one token per digit: ~80 per waypoint)
    c = b.complete(p, Sampling(temperature=0.0, max_tokens=400, seed=0, stop=p.stop, structured=True))
    res = parse_actions(c.text, expected_waypoints=p.n_waypoints, prefix=p.answer_prefix)
    assert res.status == "ok" and res.actions.shape == (p.n_waypoints, 2, 8), (res.detail, c.text)
    assert c.finish_reason == "stop" and res.detail == ""
    assert b.structured_supported is True


def test_a_server_without_json_schema_support_is_asked_again_without_it(llama_server):
    """llama-cpp-python's server takes response_format types text / json_object only: a json_schema
    one is a 422 naming the field. The backend asks once more without it and remembers."""
    base, model = llama_server
    p = real_prompts()[0]
    b = server_backend(base, model, mode="chat")
    s = Sampling(temperature=0.0, max_tokens=8, seed=0, structured=True)
    c = b.complete(p, s)
    assert b.structured_supported is False and b.requests_made == 2
    assert isinstance(c.text, str)
    b.complete(p, s)  # not offered again: one request
    assert b.requests_made == 3


# ------------------------------------------------------------------------------------------------
# error paths: each a failed trial record (parse_status llm_error), never a crash
# ------------------------------------------------------------------------------------------------

class _Stub(http.server.BaseHTTPRequestHandler):
    def do_POST(self):  # noqa: N802
        if self.path.startswith("/slow"):
            time.sleep(1.0)
        self.send_response(500)
        body = b'{"error": "boom"}'
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


@pytest.fixture()
def stub_server():
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Stub)
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}"
    srv.shutdown()
    srv.server_close()


def _trial(backend):
    ex = demo(n=4)
    return llm_predict(backend, [ex], ex[0] + 0.01, ex[1], n_steps=50, n_waypoints=2, structured=True)


@pytest.mark.parametrize("case", ["dead", "timeout", "http500"])
def test_server_failures_are_failed_trials(case, stub_server):
    if case == "dead":
        url, err = f"http://127.0.0.1:{free_port()}/v1", LLMRequestError
    elif case == "timeout":
        url, err = stub_server + "/slow/v1", LLMTimeoutError
    else:
        url, err = stub_server + "/v1", LLMRequestError
    b = OpenAIBackend(model="m", base_url=url, api_key="", mode="completions", timeout_s=0.2, max_retries=1,
                      backoff_s=0.01)
    with pytest.raises(err) as e:
        b.complete(real_prompts()[0], Sampling(max_tokens=8))
    assert isinstance(e.value, LLMError) and "\n" not in str(e.value)
    if case == "http500":
        assert e.value.status == 500
    actions, fields = _trial(b)
    assert actions is None and fields["parse_status"] == "llm_error"
    assert fields["parse_detail"].startswith(type(e.value).__name__)


def test_llm_eval_command_with_the_openai_backend_against_the_real_server(llama_server, prefect_api, warehouse):
    """`demoforge llm-eval --backend openai` on its main path, against llama-cpp-python's server rather
    than a Python stub: its options reach the backend (URL, model, completions mode, 2 waypoints in the
    compact number format; free text: the grammar through this server is
    test_structured_answer_through_the_server_parses's), and the trial row records what the server said."""
    from typer.testing import CliRunner

    from demoforge.cli import app
    from demoforge.schemas.catalog import query
    from tests.support.episodes import SCRIPTED_TAKE as TAKE, scripted_database

    base, model = llama_server
    scripted_database(warehouse, n=12)              # a pouring database from the scripted demonstration
    r = CliRunner().invoke(app, ["llm-eval", "--task", "pouring", "--strategy", "single", "--trials", "1",
                                 "--backend", "openai", "--base-url", base, "--model", model, "--api-mode", "completions",
                                 "--free", "--number-format", "compact", "--waypoints", "2"],
                           env={"OPENAI_API_KEY": ""})
    assert r.exit_code == 0, r.output
    rows = query("SELECT * FROM llm_trials", warehouse).to_pylist()
    assert len(rows) == 1, rows
    t = rows[0]
    assert (t["task"], t["take"], t["strategy"], t["backend"], t["model"]) == ("pouring", TAKE, "single", "openai", model)
    assert t["retrieved_episode_ids"] == [0] and t["n_waypoints"] == 2 and not t["cached"]
    # the server's own token counts and its answer in the compact format, parsed
    assert t["prompt_tokens"] > 100 and t["answer_tokens"] > 0 and t["latency_s"] > 0
    assert t["parse_status"] == "ok", (t["parse_detail"], t["raw_answer"])
    assert "." not in t["raw_answer"]                 # compact: integers (mm, quaternions x 100)
    assert t["success"] or t["failure_reason"], t    # judged in MuJoCo
    assert t["sim_detail"] and "single" in r.output  # report_table3, printed
