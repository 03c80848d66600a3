"""LLM backends behind one interface, and a registry.

    backend = get_backend("local")                       # Gemma 3 270M GGUF via llama.cpp (default)
    backend = get_backend("openai", model="gpt-4o-mini") # any OpenAI-compatible endpoint
    backend = get_backend("local", cache_dir="warehouse/_llm_cache")   # wrapped in CachedBackend
    c = backend.complete(prompt, Sampling(temperature=0.0, max_tokens=2048, seed=0))
    c.text, c.prompt_tokens, c.completion_tokens, c.latency_s, c.finish_reason, c.cached

A backend gets a :class:`demoforge.lib.llm.prompting.Prompt` and uses ``prompt.messages`` (chat endpoints) or
``prompt.text`` (completion / base models).  Backends: ``local`` (embedded default), ``openai``,
``fake`` (scripted answers, for tests and dry runs).
"""

from __future__ import annotations

from typing import Any

from demoforge.lib.registry import Registry
from demoforge.lib.llm.base import (Completion, FakeBackend, LLMBackend, LLMBudgetExceeded, LLMError,
                                    LLMRequestError, LLMTimeoutError, Sampling)

__all__ = [
    "Sampling",
    "Completion",
    "LLMBackend",
    "LLMError",
    "LLMRequestError",
    "LLMTimeoutError",
    "LLMBudgetExceeded",
    "FakeBackend",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "get_backend",
]

DEFAULT_BACKEND = "local"

#: name -> the backend's class, imported on first use (llama.cpp, the HTTP client); an unknown name is an
#: UnknownNameError (a user error, and a ValueError) listing the names
BACKENDS: Registry[type[LLMBackend]] = Registry("LLM backend", {
    "local": "demoforge.lib.llm.local_backend:LocalBackend",
    "openai": "demoforge.lib.llm.openai_backend:OpenAIBackend",
    "fake": "demoforge.lib.llm.base:FakeBackend",
})


def get_backend(name: str = DEFAULT_BACKEND, cache_dir: Any = None, **options: Any) -> LLMBackend:
    """A backend by registry name (any case), built with ``options``; with ``cache_dir`` wrapped in
    :class:`demoforge.lib.llm.cache.CachedBackend`. An unknown name is an UnknownNameError listing the names."""
    backend = BACKENDS.get((name or "").strip().lower())(**options)
    if cache_dir is not None:
        from demoforge.lib.llm.cache import CachedBackend  # lazy: the package's import stays free of numpy

        backend = CachedBackend(backend, cache_dir)
    return backend
