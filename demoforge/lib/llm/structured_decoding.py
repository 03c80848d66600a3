"""Greedy decoding under the action-list grammar, without llama.cpp's grammar sampler.

llama.cpp applies a GBNF grammar by testing every one of the vocabulary's tokens against it at every
step. Gemma's vocabulary has 262,144 tokens, so on these 2 cores a structured answer ran at about
15 tokens/s against 35 free-running (a 4,250-token compact prompt, 300 answer tokens; 2026-11-25).
The action list needs far less: its characters are digits, ``-``, ``.``, ``,``, ``[``, ``]`` and a
newline, and only a few hundred tokens are made of them alone.

* :class:`ActionListLanguage` is the character automaton of :func:`demoforge.lib.llm.grammar.actions_gbnf`
  (same rows, number bounds, optional newline between waypoints, ``prefix``): it accepts exactly the
  strings that grammar accepts.
* :func:`greedy_structured` evaluates the prompt, then at each step takes the highest-logit token
  among those made of the action list's characters that the automaton accepts whole. That is the
  token llama.cpp's grammar sampler picks greedily (it, too, keeps a token only if its whole text is
  accepted, and otherwise takes the argmax, lowest id first on ties); once the list is closed it stops,
  where llama.cpp would admit only end-of-generation. The answers are therefore the grammar path's,
  token for token (tests/lib/llm/test_structured_decoding.py compares them on real prompts).

Only greedy decoding (temperature 0) takes this path; sampling at a temperature keeps the GBNF sampler.
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from demoforge.lib.llm.grammar import answer_spec

__all__ = ["ALPHABET", "ActionListLanguage", "DecodeResult", "action_tokens", "greedy_structured",
           "language_for_prompt", "token_piece"]

ALPHABET = frozenset("0123456789-.,[]\n")
_OPEN = "[[["
_DONE = ("done",)


@dataclass(frozen=True)
class ActionListLanguage:
    """Strings of ``actions_gbnf(n_keyframes, precision, prefix, max_rows, int_digits)``.

    A state is a small tuple; :meth:`advance` consumes a text and returns the new state, or None when
    the text leaves the language. ``rows_min``/``rows_max``: waypoint count bounds (equal for a fixed
    count)."""

    rows_min: int
    rows_max: int
    precision: int = 3
    prefix: str = ""
    int_digits: int = 2

    def __post_init__(self):
        if not _OPEN.startswith(self.prefix):
            raise ValueError(f"prefix must be a prefix of {_OPEN!r}, got {self.prefix!r}")
        if not 1 <= self.rows_min <= self.rows_max:
            raise ValueError(f"need 1 <= rows_min <= rows_max, got {self.rows_min}, {self.rows_max}")
        if self.precision < 0 or self.int_digits < 1:
            raise ValueError("precision must be >= 0 and int_digits >= 1")

    # -- states: ("open", i) | ("value", row, arm, field, phase, count, rot) | ("sep", row, arm, field, i, rot)
    #            | ("rowsep", row, stage) | ("done",)
    # rot: a non-zero digit was seen in this arm's quaternion (fields 3-6); a quaternion of four zeros is
    # refused at its last comma, as the grammar's ``quat`` rule refuses it
    def start(self) -> tuple:
        rest = _OPEN[len(self.prefix):]
        return ("open", 0) if rest else self._value_start(0, 0, 0)

    @staticmethod
    def _value_start(row: int, arm: int, field: int, rot: bool = False) -> tuple:
        return ("value", row, arm, field, "grip" if field == 7 else "start", 0, rot)

    @staticmethod
    def _separator(arm: int, field: int) -> str:
        if field < 7:
            return ","
        return "],[" if arm == 0 else "]]"

    def accepting(self, state: tuple | None) -> bool:
        return state == _DONE

    def advance(self, state: tuple | None, text: str) -> tuple | None:
        for ch in text:
            if state is None:
                return None
            state = self._step(state, ch)
        return state

    def _step(self, s: tuple, ch: str) -> tuple | None:
        kind = s[0]
        if kind == "open":
            rest = _OPEN[len(self.prefix):]
            if ch != rest[s[1]]:
                return None
            return ("open", s[1] + 1) if s[1] + 1 < len(rest) else self._value_start(0, 0, 0)
        if kind == "value":
            _, row, arm, field, phase, count, rot = s
            nxt = self._value_step(phase, count, ch)
            if nxt is not None:
                rot = rot or (3 <= field <= 6 and "1" <= ch <= "9")
                if field == 6 and not rot and not self._can_grow(*nxt):
                    return None  # a full-length zero as the last component: no way left to a non-zero quaternion
                return ("value", row, arm, field) + nxt + (rot,)
            if phase in ("int", "dec", "gripped"):  # the value may end here: the separator begins
                return self._sep_step(("sep", row, arm, field, 0, rot), ch)
            return None
        if kind == "sep":
            return self._sep_step(s, ch)
        if kind == "rowsep":
            _, row, stage = s
            done_rows = row + 1
            if stage == 0:
                if ch == "]" and done_rows >= self.rows_min:
                    return _DONE
                if ch == "," and done_rows < self.rows_max:
                    return ("rowsep", row, 1)
                return None
            if stage == 1 and ch == "\n":
                return ("rowsep", row, 2)
            if stage in (1, 2) and ch == "[":
                return ("rowsep", row, 3)
            if stage == 3 and ch == "[":
                return self._value_start(row + 1, 0, 0)
            return None
        return None  # done: nothing may follow

    def _value_step(self, phase: str, count: int, ch: str) -> tuple | None:
        digit = "0" <= ch <= "9"
        if phase == "grip":
            return ("gripped", 0) if ch in "01" else None
        if phase == "start":
            if ch == "-":
                return ("sign", 0)
            return ("int", 1) if digit else None
        if phase == "sign":
            return ("int", 1) if digit else None
        if phase == "int":
            if digit and count < self.int_digits:
                return ("int", count + 1)
            if ch == "." and self.precision > 0:
                return ("dot", 0)
            return None
        if phase == "dot":
            return ("dec", 1) if digit else None
        if phase == "dec":
            return ("dec", count + 1) if digit and count < self.precision else None
        return None

    def _can_grow(self, phase: str, count: int) -> bool:
        """Whether a number in this phase may take one more digit (directly or after a point)."""
        if phase == "int":
            return count < self.int_digits or self.precision > 0
        if phase == "dec":
            return count < self.precision
        return phase in ("start", "sign", "dot")

    def _sep_step(self, s: tuple, ch: str) -> tuple | None:
        _, row, arm, field, i, rot = s
        sep = self._separator(arm, field)
        if ch != sep[i] or (field == 6 and not rot):
            return None
        if i + 1 < len(sep):
            return ("sep", row, arm, field, i + 1, rot)
        if field < 7:
            return self._value_start(row, arm, field + 1, rot)
        if arm == 0:
            return self._value_start(row, 1, 0)
        return ("rowsep", row, 0)


def language_for_prompt(prompt: Any, text: str, max_rows: int) -> ActionListLanguage:
    """The language :func:`demoforge.lib.llm.grammar.structured_grammar` compiles for ``prompt``."""
    n, precision, prefix, int_digits = answer_spec(prompt, text)
    lo, hi = (n, n) if n is not None else (1, int(max_rows))
    return ActionListLanguage(lo, hi, precision, prefix, int_digits)


_PIECES: dict[int, tuple[np.ndarray, list[str], Any]] = {}  # id(model) -> ids, texts, the model
_PIECES_LOCK = threading.Lock()


def token_piece(vocab, tok: int, buf) -> str | None:
    """The text of token ``tok`` as llama.cpp's grammar sees it (special tokens rendered), None when it
    is empty or not whole UTF-8. ``buf``: a ctypes string buffer reused across calls."""
    import llama_cpp

    n = llama_cpp.llama_token_to_piece(vocab, tok, buf, len(buf), 0, True)
    if n <= 0:
        return None
    try:
        return buf.raw[:n].decode("utf-8")
    except UnicodeDecodeError:
        return None


def action_tokens(llm) -> tuple[np.ndarray, list[str]]:
    """Ids and texts of the tokens of ``llm``'s vocabulary made only of :data:`ALPHABET` characters
    (their text as llama.cpp's grammar sees it: the token's piece, special tokens rendered).
    Computed once per loaded model."""
    key = id(llm)
    with _PIECES_LOCK:
        hit = _PIECES.get(key)
        if hit is not None and hit[2] is llm:
            return hit[0], hit[1]
        vocab = llm._model.vocab
        buf = ctypes.create_string_buffer(256)
        ids, texts = [], []
        for tok in range(llm.n_vocab()):
            piece = token_piece(vocab, tok, buf)
            if piece and set(piece) <= ALPHABET:
                ids.append(tok)
                texts.append(piece)
        order = np.asarray(ids, dtype=np.int64)
        _PIECES[key] = (order, texts, llm)
        return order, texts


@dataclass(frozen=True)
class DecodeResult:
    text: str
    tokens: list[int]
    finish_reason: str  # "stop": the list was closed; "length": max_tokens reached first
    prompt_tokens: int


def greedy_structured(llm, prompt_tokens: list[int], language: ActionListLanguage, max_tokens: int,
                      reuse_prefix: bool = False) -> DecodeResult:
    """Greedy answer of ``llm`` (a llama_cpp.Llama) to ``prompt_tokens`` within ``language``.

    ``reuse_prefix``: keep the KV cache of the longest common prefix with what the model evaluated last
    (only valid with a full, not windowed, cache, as llama-cpp-python's own prefix reuse)."""
    ids, texts = action_tokens(llm)
    n_vocab = llm.n_vocab()
    prompt_tokens = list(prompt_tokens)
    if not prompt_tokens:
        raise ValueError("empty prompt")
    keep = 0
    if reuse_prefix and llm.n_tokens:
        seen = llm.input_ids[: llm.n_tokens]
        m = min(len(seen), len(prompt_tokens) - 1)  # at least one token is evaluated: it gives the logits
        while keep < m and seen[keep] == prompt_tokens[keep]:
            keep += 1
    if keep:
        llm.n_tokens = keep  # eval() drops the cache beyond n_tokens before decoding
    else:
        llm.reset()
    llm.eval(prompt_tokens[keep:])
    state = language.start()
    out: list[int] = []
    while len(out) < max_tokens and not language.accepting(state):
        logits = np.ctypeslib.as_array(llm._ctx.get_logits_ith(-1), shape=(n_vocab,))
        cand = logits[ids]
        # highest logit first; a stable sort keeps the lower id first among equal logits (llama.cpp's argmax)
        order = np.argsort(-cand, kind="stable")
        for j in order:
            nxt = language.advance(state, texts[j])
            if nxt is not None:
                break
        else:  # cannot happen while single digits and brackets are tokens; loud if a vocabulary lacks them
            raise RuntimeError(f"no token continues the action list in state {state}")
        tok = int(ids[j])
        out.append(tok)
        state = nxt
        if language.accepting(state):
            break
        llm.eval([tok])
    finish = "stop" if language.accepting(state) and len(out) < max_tokens else "length"
    text = llm.detokenize(out).decode("utf-8", errors="replace")
    return DecodeResult(text=text, tokens=out, finish_reason=finish, prompt_tokens=len(prompt_tokens))
