"""Structured output: answers that always parse.

* :func:`actions_gbnf` — a llama.cpp GBNF grammar admitting only the action-list syntax the prompt
  shows (:func:`demoforge.lib.llm.prompting.format_actions`): ``[[[l0,...,l7],[r0,...,r7]],\\n[[...]]]``
  with exactly ``n_keyframes`` waypoints of 2 x 8 numbers.  Numbers are bounded (optional ``-``, 1-2
  integer digits, at most ``precision`` decimals; the gripper state is ``0`` or ``1`` as the prompt
  writes it), so a constrained generation cannot run away inside a number, and after the closing
  ``]]]`` llama.cpp admits only end-of-generation.  A quaternion of four zeros (no rotation: the
  parser's ``zero_quaternion``) is outside the language: one of its four numbers has a non-zero
  digit.  ``prefix``: what the prompt already opened (the completion text ends with ``[[[``), the
  grammar starts after it.
* ``n_keyframes=None`` (a count the caller does not fix): 1..``max_rows`` waypoints, default 64 —
  the keyframe prompts' examples have 5-30 keyframes and uniform ones ~20, so 64 never cuts a
  plausible answer while still bounding a runaway list (64 x 16 numbers ~ 6k tokens).
* :func:`actions_json_schema` — the same constraint as a JSON schema (``{"actions": n x 2 x 8}``) for
  OpenAI-style ``response_format={"type": "json_schema", ...}``.  Such a JSON answer needs no reader
  of its own: :func:`demoforge.lib.llm.prompting.parse_actions` already takes the first (n, 2, 8)
  array inside ``{"actions": ...}`` (tests/lib/llm/test_grammar.py checks it).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from demoforge.lib.llm.number_format import get_number_format

__all__ = ["MAX_ROWS", "GRAMMAR_VERSION", "actions_gbnf", "actions_json_schema", "response_format", "llama_grammar",
           "structured_grammar", "prompt_gbnf", "answer_rows", "answer_spec", "opened_prefix"]

MAX_ROWS = 64
GRAMMAR_VERSION = 2  # a structured answer's cache key holds it; 2: no quaternion of four zeros
_OPEN = "[[["  # outer list, first waypoint, its left arm


def _rows_spec(n_keyframes: int | None, max_rows: int) -> tuple[int, int]:
    if n_keyframes is None:
        if max_rows < 1:
            raise ValueError("max_rows must be >= 1")
        return 1, int(max_rows)
    n = int(n_keyframes)
    if n < 1:
        raise ValueError(f"n_keyframes must be >= 1, got {n_keyframes!r}")
    return n, n


def _rep(item: str, lo: int, hi: int) -> str:
    """``item`` repeated lo..hi times in GBNF ("" for none)."""
    if hi <= 0:
        return ""
    if lo == hi:
        return item if lo == 1 else f"{item}{{{lo}}}"
    return f"{item}{{{lo},{hi}}}"


def _seq(*parts: str) -> str:
    return " ".join(p for p in parts if p)


def actions_gbnf(n_keyframes: int | None, precision: int = 3, prefix: str = "", max_rows: int = MAX_ROWS,
                 int_digits: int = 2) -> str:
    """GBNF grammar of an (n_keyframes, 2, 8) action list written as the prompt writes it.  ``prefix``
    must be a prefix of ``[[[`` (``""``: the answer starts from scratch, e.g. a chat answer);
    ``int_digits``: most digits before the point (2 for metres, 4 for the compact format's mm)."""
    if not _OPEN.startswith(prefix):
        raise ValueError(f"prefix must be a prefix of {_OPEN!r}, got {prefix!r}")
    if int(precision) < 0:
        raise ValueError("precision must be >= 0")
    if int(int_digits) < 1:
        raise ValueError("int_digits must be >= 1")
    lo, hi = _rows_spec(n_keyframes, max_rows)
    rest = _OPEN[len(prefix):]
    head = f'"{rest}" ' if rest else ""
    more_lo, more_hi = lo - 1, hi - 1
    if more_hi == 0:
        more = ""
    elif more_lo == more_hi:
        more = f" more{{{more_lo}}}"
    else:
        more = f" more{{{more_lo},{more_hi}}}"
    p, k = int(precision), int(int_digits)
    dec = f' ("." [0-9]{{1,{p}}})?' if p > 0 else ""
    zero_dec = f' ("." "0"{{1,{p}}})?' if p > 0 else ""
    # a number with a non-zero digit: the first one at integer place j, or (integer part all zeros) at
    # decimal place j; the digits around it stay within the same bounds as ``num``
    nz_int = " | ".join(_seq(_rep('"0"', j, j), "[1-9]", _rep("[0-9]", 0, k - 1 - j)) + dec for j in range(k))
    nz_dec = " | ".join(_seq(_rep('"0"', 1, k), '"."', _rep('"0"', j, j), "[1-9]", _rep("[0-9]", 0, p - 1 - j))
                        for j in range(p))
    return "\n".join([
        f'root ::= {head}arm "],[" arm "]]"{more} "]"',
        'more ::= "," "\\n"? "[[" arm "],[" arm "]]"',
        'arm  ::= num "," num "," num "," quat "," grip',
        # a quaternion of four zeros is no rotation (the parser's zero_quaternion): one value must not be 0
        'quat ::= nz "," num "," num "," num | zero "," nz "," num "," num'
        ' | zero "," zero "," nz "," num | zero "," zero "," zero "," nz',
        f'num  ::= "-"? [0-9]' + ' [0-9]?' * (k - 1) + dec,
        f'zero ::= "-"? "0"{{1,{k}}}{zero_dec}',
        f'nz   ::= "-"? ({nz_int}' + (f' | {nz_dec}' if p > 0 else "") + ")",
        'grip ::= "0" | "1"',
        "",
    ])


def longest_answer_chars(n_keyframes: int, precision: int = 3, prefix: str = "", int_digits: int = 2) -> int:
    """Characters of the longest answer :func:`actions_gbnf` admits for exactly ``n_keyframes`` rows, every
    optional newline taken. Every token is at least one character, so this also bounds the tokens a
    structured answer can need: a ``max_tokens`` at least this large never cuts one."""
    if not _OPEN.startswith(prefix):
        raise ValueError(f"prefix must be a prefix of {_OPEN!r}, got {prefix!r}")
    num = 1 + int(int_digits) + (1 + int(precision) if int(precision) > 0 else 0)   # "-", digits, ".", decimals
    arm = 7 * num + 7 + 1                                                          # 7 numbers, 7 commas, grip
    first = len(_OPEN) - len(prefix) + arm + len("],[") + arm + len("]]")
    more = len(",\n[[") + arm + len("],[") + arm + len("]]")
    return first + (int(n_keyframes) - 1) * more + len("]")


def actions_json_schema(n_keyframes: int | None, max_rows: int = MAX_ROWS) -> dict:
    """JSON schema of ``{"actions": [[[8 numbers], [8 numbers]], ...]}`` with n_keyframes waypoints."""
    lo, hi = _rows_spec(n_keyframes, max_rows)

    def arr(items: dict, n_min: int, n_max: int) -> dict:
        return {"type": "array", "items": items, "minItems": n_min, "maxItems": n_max}

    actions = arr(arr(arr({"type": "number"}, 8, 8), 2, 2), lo, hi)
    return {"type": "object", "properties": {"actions": actions}, "required": ["actions"],
            "additionalProperties": False}


def response_format(n_keyframes: int | None, max_rows: int = MAX_ROWS) -> dict:
    """The OpenAI ``response_format`` of :func:`actions_json_schema`."""
    return {"type": "json_schema",
            "json_schema": {"name": "actions", "strict": True, "schema": actions_json_schema(n_keyframes, max_rows)}}


@lru_cache(maxsize=32)
def llama_grammar(n_keyframes: int | None, precision: int = 3, prefix: str = "", max_rows: int = MAX_ROWS,
                  int_digits: int = 2):
    """The compiled ``llama_cpp.LlamaGrammar`` of :func:`actions_gbnf` (cached per row count)."""
    from llama_cpp import LlamaGrammar

    return LlamaGrammar.from_string(actions_gbnf(n_keyframes, precision, prefix, max_rows, int_digits), verbose=False)


def prompt_gbnf(prompt: Any, text: str) -> str:
    """The GBNF grammar of ``prompt``'s answer, as :func:`structured_grammar` compiles it (for servers
    that take the grammar as text)."""
    n, precision, prefix, int_digits = answer_spec(prompt, text)
    return actions_gbnf(n, precision, prefix, MAX_ROWS, int_digits)


def answer_rows(prompt: Any) -> int | None:
    """The waypoint count ``prompt`` asks for (``prompt.n_waypoints``), None when it fixes none."""
    return int(getattr(prompt, "n_waypoints", 0) or 0) or None


def answer_spec(prompt: Any, text: str) -> tuple[int | None, int, str, int]:
    """(waypoint count or None, precision, opened prefix, integer digits) of ``prompt``'s answer."""
    fmt = get_number_format(getattr(prompt, "number_format", None))
    return answer_rows(prompt), int(getattr(prompt, "precision", 3)), opened_prefix(text), fmt.int_digits


def structured_grammar(prompt: Any, text: str):
    """The compiled grammar for ``prompt``: its answer's waypoint count (``prompt.n_waypoints``; 0 or
    absent: 1..MAX_ROWS), its precision, and whatever part of ``[[[`` the completion text already opened."""
    n, precision, prefix, int_digits = answer_spec(prompt, text)
    return llama_grammar(n, precision, prefix, MAX_ROWS, int_digits)


def opened_prefix(text: str) -> str:
    """The longest prefix of ``[[[`` that ``text`` ends with (what a completion continues after)."""
    for k in range(len(_OPEN), 0, -1):
        if text.endswith(_OPEN[:k]):
            return _OPEN[:k]
    return ""
