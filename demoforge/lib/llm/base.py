"""The LLM interface: what a backend is asked (:class:`Sampling`), what it answers (:class:`Completion`),
its errors, and the scripted :class:`FakeBackend` for tests and dry runs. The registry is the package's
:func:`demoforge.lib.llm.get_backend`."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable, Sequence


class LLMError(RuntimeError):
    """Any backend failure.  Messages never contain API keys."""


class LLMRequestError(LLMError):
    """The endpoint answered with an error (``status``: HTTP status, None for connection errors)."""

    def __init__(self, message: str, status: int | None = None, attempts: int = 1):
        super().__init__(message)
        self.status = status
        self.attempts = attempts


class LLMTimeoutError(LLMRequestError):
    """Every attempt timed out."""


class LLMBudgetExceeded(LLMError):
    """The per-run cap on requests or tokens is reached."""


@dataclass(frozen=True)
class Sampling:
    temperature: float = 0.0
    top_p: float = 1.0
    max_tokens: int = 2048
    seed: int | None = 0
    stop: tuple[str, ...] = ()
    # constrained decoding of the action list (demoforge.lib.llm.grammar): the local backend samples
    # under a GBNF grammar, the openai one asks for a JSON schema / grammar.  Part of the cache key
    # (to_dict), so a free-running answer is never served for a structured request.
    structured: bool = False

    def __post_init__(self):
        # lists are accepted for convenience; stored as a tuple (hashable, stable cache key)
        if not isinstance(self.stop, tuple):
            object.__setattr__(self, "stop", tuple(self.stop or ()))
        if self.max_tokens < 1:
            raise ValueError("max_tokens must be >= 1")
        if self.temperature < 0:
            raise ValueError("temperature must be >= 0")
        if not (0 < self.top_p <= 1):
            raise ValueError("top_p must be in (0, 1]")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["stop"] = list(self.stop)
        return d


@dataclass(frozen=True)
class Completion:
    text: str
    prompt_tokens: int
    completion_tokens: int
    latency_s: float
    finish_reason: str | None
    cached: bool = False
    backend: str = ""
    model: str = ""
    usage_source: str = ""  # "api" (endpoint's usage), "tokenizer" (real local count), "estimate"

    @property
    def total_tokens(self) -> int:
        return int(self.prompt_tokens) + int(self.completion_tokens)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Completion":
        names = cls.__dataclass_fields__.keys()
        return cls(**{k: v for k, v in d.items() if k in names})

    def as_cached(self) -> "Completion":
        return replace(self, cached=True)


class LLMBackend(ABC):
    """name: registry name; model: model identifier.  Subclasses implement :meth:`complete`."""

    name: str = "base"
    model: str = ""

    @abstractmethod
    def complete(self, prompt: Any, sampling: Sampling) -> Completion:
        ...

    def count_tokens(self, text: str) -> int | None:
        """Real token count if the backend has a tokenizer, else None (callers fall back to
        ``demoforge.lib.llm.prompting.approx_token_count``)."""
        return None

    def cache_identity(self) -> dict:
        """What, besides name and model, makes two backends' answers differ (no secrets)."""
        return {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, model={self.model!r})"


class FakeBackend(LLMBackend):
    """Scripted answers: ``responses`` is a list (cycled) of strings, or a callable(prompt, sampling) -> str.
    Token counts are estimates.  For tests and dry runs of the pipeline."""

    name = "fake"

    def __init__(self, responses: Sequence[str] | Callable[[Any, Sampling], str] = ("",), model: str = "fake"):
        self.model = model
        self._responses = responses
        self.calls = 0

    def complete(self, prompt: Any, sampling: Sampling) -> Completion:
        from demoforge.lib.llm.prompting import approx_token_count  # lazy (CLI --help): numpy, scipy

        if callable(self._responses):
            text = self._responses(prompt, sampling)
        else:
            text = self._responses[self.calls % len(self._responses)]
        self.calls += 1
        return Completion(text=text, prompt_tokens=approx_token_count(getattr(prompt, "text", str(prompt))),
                          completion_tokens=approx_token_count(text), latency_s=0.0, finish_reason="stop",
                          backend=self.name, model=self.model, usage_source="estimate")

    def cache_identity(self) -> dict:
        return {"responses": None if callable(self._responses) else list(self._responses)}
