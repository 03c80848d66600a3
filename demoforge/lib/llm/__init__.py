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

import importlib
from typing import Any

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

BACKENDS: dict[str, str] = {
    "local": "demoforge.lib.llm.local_backend:LocalBackend",
    "openai": "demoforge.lib.llm.openai_backend:OpenAIBackend",
    "fake": "demoforge.lib.llm.base:FakeBackend",
}


def get_backend(name: str = DEFAULT_BACKEND, cache_dir: Any = None, **options: Any) -> LLMBackend:
    """A backend by registry name, built with ``options``; with ``cache_dir`` wrapped in
    :class:`demoforge.lib.llm.cache.CachedBackend`.  Unknown names raise ValueError listing the choices."""
    key = (name or "").strip().lower()
    if key not in BACKENDS:
        raise ValueError(f"unknown LLM backend {name!r}; choices: {', '.join(sorted(BACKENDS))}")
    mod_name, cls_name = BACKENDS[key].split(":")
    cls = getattr(importlib.import_module(mod_name), cls_name)
    backend = cls(**options)
    if cache_dir is not None:
        from demoforge.lib.llm.cache import CachedBackend  # lazy: the package's import stays free of numpy

        backend = CachedBackend(backend, cache_dir)
    return backend
