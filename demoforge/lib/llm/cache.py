"""A disk cache of LLM answers.

Key = sha256 of JSON {backend name, model, backend.cache_identity() (no secrets), prompt content
hash, sampling parameters, cache format version, and for structured answers the grammar's version}.  One JSON file per answer at
``<cache_dir>/<key[:2]>/<key>.json``, written atomically (temporary file in the same folder, fsync,
``os.replace``), so a crash never leaves a half-written answer and concurrent writers of the same key
are harmless.  A corrupt or unreadable file counts as a miss and is overwritten.  A hit returns the
stored :class:`Completion` unchanged except ``cached=True`` (same text, token counts and the original
latency) and costs no request.  API keys never enter the key or the files: backends expose only
``name``, ``model`` and ``cache_identity()``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from demoforge.lib.llm.base import Completion, LLMBackend, Sampling
from demoforge.lib.llm.grammar import GRAMMAR_VERSION

CACHE_FORMAT = 1


def _prompt_hash(prompt: Any) -> str:
    h = getattr(prompt, "content_hash", None)
    if h:
        return str(h)
    return hashlib.sha256(str(prompt).encode("utf-8")).hexdigest()


def cache_key(backend: LLMBackend, prompt: Any, sampling: Sampling) -> str:
    blob = json.dumps({
        "format": CACHE_FORMAT,
        "backend": backend.name,
        "model": backend.model,
        "identity": backend.cache_identity(),
        "prompt": _prompt_hash(prompt),
        "sampling": sampling.to_dict(),
        **({"grammar": GRAMMAR_VERSION} if sampling.structured else {}),
    }, sort_keys=True, ensure_ascii=True, default=str)
    return hashlib.sha256(blob.encode("utf-8")).hexdigest()


class CachedBackend(LLMBackend):
    """Wraps a backend; answers are read from / written to ``cache_dir``."""

    def __init__(self, backend: LLMBackend, cache_dir: str | os.PathLike):
        self.backend = backend
        self.name = backend.name
        self.model = backend.model
        self.cache_dir = Path(cache_dir)
        self.hits = 0
        self.misses = 0

    def path_for(self, prompt: Any, sampling: Sampling) -> Path:
        key = cache_key(self.backend, prompt, sampling)
        return self.cache_dir / key[:2] / f"{key}.json"

    def lookup(self, prompt: Any, sampling: Sampling) -> Completion | None:
        p = self.path_for(prompt, sampling)
        try:
            rec = json.loads(p.read_text(encoding="utf-8"))
            return Completion.from_dict(rec["completion"]).as_cached()
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def complete(self, prompt: Any, sampling: Sampling) -> Completion:
        hit = self.lookup(prompt, sampling)
        if hit is not None:
            self.hits += 1
            return hit
        self.misses += 1
        c = self.backend.complete(prompt, sampling)
        self._store(prompt, sampling, c)
        return c

    def _store(self, prompt: Any, sampling: Sampling, c: Completion) -> None:
        p = self.path_for(prompt, sampling)
        p.parent.mkdir(parents=True, exist_ok=True)
        rec = {
            "format": CACHE_FORMAT,
            "key": p.stem,
            "backend": self.backend.name,
            "model": self.backend.model,
            "prompt_hash": _prompt_hash(prompt),
            "sampling": sampling.to_dict(),
            "completion": c.to_dict() | {"cached": False},
        }
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=p.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(rec, f, ensure_ascii=False, indent=1)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, p)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise

    def count_tokens(self, text: str) -> int | None:
        return self.backend.count_tokens(text)

    def cache_identity(self) -> dict:
        return self.backend.cache_identity()

    def __repr__(self) -> str:
        return f"CachedBackend({self.backend!r}, cache_dir={str(self.cache_dir)!r})"
