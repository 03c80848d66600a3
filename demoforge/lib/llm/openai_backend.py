"""Any OpenAI-compatible HTTP endpoint (OpenAI, vLLM, Ollama, llama.cpp server), standard library only.

* ``base_url`` / ``model`` / ``api_key`` from the constructor, else the environment
  (``OPENAI_BASE_URL``, default https://api.openai.com/v1; ``DEMOFORGE_LLM_MODEL``; ``OPENAI_API_KEY``,
  optional for local servers).
* ``mode="chat"`` posts ``prompt.messages`` to ``/chat/completions``; ``mode="completions"`` posts
  ``prompt.text`` to ``/completions`` (base models behind vLLM / llama.cpp server).
* Retries with exponential backoff (``backoff_s * 2**attempt``, capped at ``max_backoff_s``; a 429's
  ``Retry-After`` is honoured up to that cap) on timeouts, connection errors, HTTP 5xx and 429; other
  4xx fail at once.  ``max_retries`` retries after the first attempt.
* Per-run caps (per backend instance): ``max_requests`` HTTP attempts (retries count: they cost) and
  ``max_total_tokens`` prompt + completion tokens; a call when a cap is reached raises
  :class:`LLMBudgetExceeded` before anything is sent.  Token usage comes from the response's
  ``usage`` when present, else the approximate count (``usage_source="estimate"``).
* The API key is held privately: it is never logged, never in an exception message (server error
  bodies are redacted), never in ``repr``, pickles (re-read from the environment on unpickling) or
  cache keys (``cache_identity`` = base URL without credentials / query, and mode).
* ``Sampling(structured=True)``: chat mode sends ``response_format`` with the action list's JSON schema
  (:func:`demoforge.lib.llm.grammar.response_format`; OpenAI, vLLM and llama.cpp's ``llama-server``
  honour it); completions mode sends the GBNF grammar in a ``grammar`` field instead — the completion
  continues ``prompt.text`` after its opened ``[[[``, which a JSON object cannot do, and the servers
  that serve base models on ``/completions`` (llama.cpp's ``llama-server``, ``python -m
  llama_cpp.server``) take ``grammar``.  A server that answers 400/422 naming the field is asked
  again once without it, and this backend instance stops sending it (``structured_supported``); the
  answer is then free-running and goes through the tolerant parser.  (llama-cpp-python's server
  answers that refusal with HTTP 500: a 500 naming the field is not retried, it is the refusal.)
"""

from __future__ import annotations

import json
import logging
import socket
import time
import urllib.error
import urllib.parse
import urllib.request
from typing import Any

from demoforge.lib.llm import grammar
from demoforge.lib.llm.base import (
    Completion, LLMBackend, LLMBudgetExceeded, LLMError, LLMRequestError, LLMTimeoutError, Sampling,
)
from demoforge.lib.llm.prompting import approx_token_count
from demoforge.lib.settings import read_settings

log = logging.getLogger(__name__)

DEFAULT_BASE_URL = "https://api.openai.com/v1"


def _clean_url(url: str) -> str:
    """The URL without user:password@ and without query / fragment (safe to log and hash)."""
    p = urllib.parse.urlsplit(url)
    host = p.hostname or ""
    if p.port:
        host = f"{host}:{p.port}"
    return urllib.parse.urlunsplit((p.scheme, host, p.path.rstrip("/"), "", ""))


_REFUSAL_STATUSES = (400, 422, 500)


def _refuses_structure(e: LLMRequestError) -> bool:
    """An error answer whose message names the structured-output field (not any bad request).  500 is
    included: llama-cpp-python's server answers its own request-validation error on a json_schema
    response_format with HTTP 500 (seen with 0.3.36)."""
    msg = str(e).lower()
    return e.status in _REFUSAL_STATUSES and any(w in msg for w in ("response_format", "json_schema", "grammar"))


class OpenAIBackend(LLMBackend):
    name = "openai"

    def __init__(self, model: str | None = None, base_url: str | None = None, api_key: str | None = None,
                 mode: str = "chat", timeout_s: float = 120.0, max_retries: int = 3, backoff_s: float = 1.0,
                 max_backoff_s: float = 30.0, max_requests: int | None = 1000,
                 max_total_tokens: int | None = 5_000_000, extra_body: dict | None = None):
        settings = read_settings()
        model = model or settings.llm_model
        if not model:
            raise LLMError("openai backend: no model; pass model=... or set DEMOFORGE_LLM_MODEL")
        if mode not in ("chat", "completions"):
            raise ValueError(f"mode must be 'chat' or 'completions', got {mode!r}")
        self.model = model
        self.base_url = (base_url or settings.openai_base_url or DEFAULT_BASE_URL).rstrip("/")
        self._key_from_env = api_key is None
        self._api_key = api_key if api_key is not None else settings.openai_api_key
        self.mode = mode
        self.timeout_s = float(timeout_s)
        self.max_retries = int(max_retries)
        self.backoff_s = float(backoff_s)
        self.max_backoff_s = float(max_backoff_s)
        self.max_requests = max_requests
        self.max_total_tokens = max_total_tokens
        self.extra_body = dict(extra_body or {})
        self.structured_supported: bool | None = None  # None: not tried yet; False: the server refused it
        self.requests_made = 0
        self.prompt_tokens_used = 0
        self.completion_tokens_used = 0

    # -- secrets hygiene ------------------------------------------------------------------------
    def __repr__(self) -> str:
        return f"OpenAIBackend(model={self.model!r}, base_url={_clean_url(self.base_url)!r}, mode={self.mode!r})"

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_api_key"] = None  # never pickled; re-read from the environment
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if self._key_from_env:
            self._api_key = read_settings().openai_api_key

    def _redact(self, s: str) -> str:
        if self._api_key:
            s = s.replace(self._api_key, "***")
        return s

    def cache_identity(self) -> dict:
        return {"base_url": _clean_url(self.base_url), "mode": self.mode, "extra_body": self.extra_body}

    @property
    def total_tokens_used(self) -> int:
        return self.prompt_tokens_used + self.completion_tokens_used

    # -- request --------------------------------------------------------------------------------
    def _payload(self, prompt: Any, sampling: Sampling) -> tuple[str, dict]:
        body: dict[str, Any] = {
            "model": self.model,
            "temperature": sampling.temperature,
            "top_p": sampling.top_p,
            "max_tokens": sampling.max_tokens,
        }
        if sampling.seed is not None:
            body["seed"] = sampling.seed
        if sampling.stop:
            body["stop"] = list(sampling.stop)
        if self.mode == "chat":
            msgs = getattr(prompt, "messages", None)
            body["messages"] = list(msgs) if msgs is not None else [{"role": "user", "content": str(prompt)}]
            path = "/chat/completions"
        else:
            body["prompt"] = getattr(prompt, "text", None) or str(prompt)
            path = "/completions"
        if sampling.structured and self.structured_supported is not False:
            if self.mode == "chat":
                body["response_format"] = grammar.response_format(grammar.answer_rows(prompt))
            else:
                body["grammar"] = grammar.prompt_gbnf(prompt, body["prompt"])
        body.update(self.extra_body)
        return self.base_url + path, body

    def complete(self, prompt: Any, sampling: Sampling) -> Completion:
        try:
            c = self._complete(prompt, sampling)
        except LLMRequestError as e:
            if not (sampling.structured and self.structured_supported is not False and _refuses_structure(e)):
                raise
            log.warning("%s does not take structured output; asking again without it: %s",
                        _clean_url(self.base_url), e)
            self.structured_supported = False
            return self._complete(prompt, sampling)
        if sampling.structured and self.structured_supported is None:
            self.structured_supported = True
        return c

    def _check_budget(self) -> None:
        if self.max_requests is not None and self.requests_made >= self.max_requests:
            raise LLMBudgetExceeded(
                f"openai backend: request cap reached ({self.requests_made} of max_requests={self.max_requests})")
        if self.max_total_tokens is not None and self.total_tokens_used >= self.max_total_tokens:
            raise LLMBudgetExceeded(
                f"openai backend: token cap reached ({self.total_tokens_used} of max_total_tokens="
                f"{self.max_total_tokens})")

    def _sleep(self, attempt: int, retry_after: str | None) -> None:
        delay = min(self.backoff_s * (2 ** attempt), self.max_backoff_s)
        if retry_after:
            try:
                delay = min(max(delay, float(retry_after)), self.max_backoff_s)
            except ValueError:
                pass
        time.sleep(delay)

    def _complete(self, prompt: Any, sampling: Sampling) -> Completion:
        url, body = self._payload(prompt, sampling)
        data = json.dumps(body).encode("utf-8")
        headers = {"Content-Type": "application/json", "Accept": "application/json"}
        if self._api_key:
            headers["Authorization"] = f"Bearer {self._api_key}"
        safe_url = _clean_url(url)
        structured_sent = "response_format" in body or "grammar" in body
        last: LLMRequestError | None = None
        t_start = time.perf_counter()
        for attempt in range(self.max_retries + 1):
            self._check_budget()
            self.requests_made += 1
            req = urllib.request.Request(url, data=data, headers=headers, method="POST")
            retry_after = None
            try:
                with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                    raw = resp.read()
                return self._completion(raw, time.perf_counter() - t_start, prompt)
            except urllib.error.HTTPError as e:
                try:
                    detail = e.read(2000).decode("utf-8", "replace")
                except Exception:  # noqa: BLE001
                    detail = ""
                retry_after = e.headers.get("Retry-After") if e.headers else None
                msg = self._redact(f"{safe_url} answered HTTP {e.code}: {detail.strip()[:500]}")
                retryable = e.code == 429 or e.code >= 500
                last = LLMRequestError(msg, status=e.code, attempts=attempt + 1)
                if structured_sent and _refuses_structure(last):
                    retryable = False  # the server refuses the field: complete() asks again without it
                if not retryable:
                    raise last from None
            except (TimeoutError, socket.timeout) as e:
                last = LLMTimeoutError(f"{safe_url}: no answer within timeout_s={self.timeout_s:g}",
                                       attempts=attempt + 1)
            except urllib.error.URLError as e:
                if isinstance(e.reason, (TimeoutError, socket.timeout)):
                    last = LLMTimeoutError(f"{safe_url}: no answer within timeout_s={self.timeout_s:g}",
                                           attempts=attempt + 1)
                else:
                    last = LLMRequestError(self._redact(f"{safe_url}: connection failed: {e.reason}"),
                                           attempts=attempt + 1)
            except (ConnectionError, OSError) as e:
                last = LLMRequestError(self._redact(f"{safe_url}: connection failed: {type(e).__name__}: {e}"),
                                       attempts=attempt + 1)
            log.warning("LLM request failed (attempt %d of %d): %s", attempt + 1, self.max_retries + 1, last)
            if attempt < self.max_retries:
                self._sleep(attempt, retry_after)
        assert last is not None
        kind = type(last)
        err = kind(f"{last} (gave up after {self.max_retries + 1} attempts)", status=last.status,
                   attempts=self.max_retries + 1)
        raise err from None

    def _completion(self, raw: bytes, latency: float, prompt: Any) -> Completion:
        try:
            resp = json.loads(raw.decode("utf-8"))
            choice = resp["choices"][0]
            if self.mode == "chat":
                text = (choice.get("message") or {}).get("content") or ""
            else:
                text = choice.get("text") or ""
        except (ValueError, KeyError, IndexError, TypeError, AttributeError) as e:
            raise LLMRequestError(self._redact(f"{_clean_url(self.base_url)}: malformed response "
                                               f"({type(e).__name__}): {raw[:300]!r}")) from None
        usage = resp.get("usage") or {}
        if "prompt_tokens" in usage and "completion_tokens" in usage:
            pt, ct, src = int(usage["prompt_tokens"]), int(usage["completion_tokens"]), "api"
        else:
            ptxt = getattr(prompt, "text", None) or str(prompt)
            pt, ct, src = approx_token_count(ptxt), approx_token_count(text), "estimate"
        self.prompt_tokens_used += pt
        self.completion_tokens_used += ct
        return Completion(text=text, prompt_tokens=pt, completion_tokens=ct, latency_s=latency,
                          finish_reason=choice.get("finish_reason"), backend=self.name, model=self.model,
                          usage_source=src)
