"""The tolerant parser of an LLM's answer: the first (n, 2, 8) action array in free text.

It reads what the prompt (:mod:`demoforge.lib.llm.prompting`) asks for, a continuation of ``[[[``
from a base model, a chat answer with prose or code fences around it, and a JSON object
``{"actions": [...]}`` (structured answers, :mod:`demoforge.lib.llm.grammar`).

Parser statuses (:func:`parse_actions`, never raises)
-----------------------------------------------------
``ok``              a well-formed (n, 2, 8) finite array (quaternions normalised, g snapped to 0/1)
``truncated``       the array was cut mid-way (answer ended inside it): the complete waypoints are
                    kept if there are at least 2 (``actions`` set, ``n_kept`` = how many; detail
                    says so); with fewer than 2, ``actions`` is None
``empty``           the answer is empty / whitespace only
``no_array``        no bracketed numeric array at all (only prose)
``wrong_shape``     arrays found, but none of shape (n, 2, 8) (e.g. (n, 2, 7), (n, 3, 8), ragged)
``non_finite``      an (n, 2, 8) array with NaN / inf values
``zero_quaternion`` an (n, 2, 8) array with an all-zero (norm < 1e-8) quaternion
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from demoforge.lib.geometry import quat_normalize

__all__ = ["ANSWER_PREFIX", "ParseResult", "PARSE_STATUSES", "parse_actions"]

PARSE_STATUSES = ("ok", "truncated", "empty", "no_array", "wrong_shape", "non_finite", "zero_quaternion")

# what a completion prompt ends with (demoforge.lib.llm.prompting.build_prompt), so an answer may begin inside it
ANSWER_PREFIX = "[[["
_ZERO_QUAT = 1e-8


@dataclass
class ParseResult:
    actions: np.ndarray | None  # (n, 2, 8) or None
    status: str
    detail: str = ""
    n_kept: int = 0  # waypoints returned
    raw: str = ""  # the answer as given (the caller stores it)

    @property
    def ok(self) -> bool:
        """True when actions are usable ("ok" or "truncated" with >= 2 kept waypoints)."""
        return self.actions is not None


_TOKEN_RE = re.compile(
    r"(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![A-Za-z_]))"
    r"|(?P<nonfin>[-+]?(?:nan|infinity|inf)(?![A-Za-z_]))"
    r"|(?P<lb>\[)|(?P<rb>\])"
    r"|(?P<sep>[,\s]+)"
    r"|(?P<other>[A-Za-z_][A-Za-z_0-9]*|.)",
    re.IGNORECASE | re.DOTALL,
)

_LB, _RB, _NUM, _OTHER = 0, 1, 2, 3


def _tokenize(text: str) -> list[tuple[int, float | None]]:
    toks: list[tuple[int, float | None]] = []
    for m in _TOKEN_RE.finditer(text):
        kind = m.lastgroup
        if kind == "sep":
            continue
        if kind == "num":
            try:
                toks.append((_NUM, float(m.group(0))))
            except (ValueError, OverflowError):
                toks.append((_OTHER, None))
        elif kind == "nonfin":
            s = m.group(0).lower()
            toks.append((_NUM, float("nan") if "nan" in s else (float("-inf") if s.startswith("-") else float("inf"))))
        elif kind == "lb":
            toks.append((_LB, None))
        elif kind == "rb":
            toks.append((_RB, None))
        else:
            toks.append((_OTHER, None))
    return toks


@dataclass
class _Cand:
    value: list
    garbage: bool
    closed: bool
    start: int
    end: int  # token index after the candidate


def _candidates(toks: list[tuple[int, float | None]]) -> list[_Cand]:
    """Top-level bracketed structures, in order.  Stray closing brackets are skipped; other tokens
    inside brackets mark the candidate as garbage; an unclosed structure at the end is kept open."""
    out: list[_Cand] = []
    i, n = 0, len(toks)
    while i < n:
        if toks[i][0] != _LB:
            i += 1
            continue
        start = i
        stack: list[list] = [[]]
        garbage = False
        i += 1
        while i < n and stack:
            kind, val = toks[i]
            if kind == _LB:
                new: list = []
                stack[-1].append(new)
                stack.append(new)
            elif kind == _RB:
                done = stack.pop()
                if not stack:
                    out.append(_Cand(done, garbage, True, start, i + 1))
            elif kind == _NUM:
                stack[-1].append(val)
            else:
                garbage = True
            i += 1
        if stack:
            out.append(_Cand(stack[0], garbage, False, start, n))
    return out


def _shape(x: Any) -> tuple | None:
    """Shape of a regular nested list of numbers, None if ragged / mixed."""
    if not isinstance(x, list):
        return ()
    if not x:
        return (0,)
    subs = [_shape(e) for e in x]
    if any(s is None for s in subs) or any(s != subs[0] for s in subs):
        return None
    return (len(x),) + subs[0]


def _describe(x: Any) -> str:
    s = _shape(x)
    if s is not None:
        return str(s)
    if isinstance(x, list):
        lens = sorted({len(e) if isinstance(e, list) else 0 for e in x})
        return f"ragged ({len(x)} items, sub-lengths {lens})"
    return "scalar"


def _finish(arr: np.ndarray) -> tuple[str, np.ndarray | None, str]:
    """Validate / normalise an (n, 2, 8) array."""
    if not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).sum())
        return "non_finite", None, f"{bad} non-finite value(s) in an {arr.shape} array"
    q = arr[:, :, 3:7]
    norms = np.linalg.norm(q, axis=-1)
    if (norms < _ZERO_QUAT).any():
        w = np.argwhere(norms < _ZERO_QUAT)[0]
        return "zero_quaternion", None, f"zero quaternion at waypoint {int(w[0])}, arm {int(w[1])}"
    out = arr.copy()
    out[:, :, 3:7] = q / norms[..., None]
    out[:, :, 7] = (arr[:, :, 7] >= 0.5).astype(np.float64)
    return "ok", out, ""


def _squeeze(val: list) -> list:
    while isinstance(val, list) and len(val) == 1 and isinstance(val[0], list) and _depth(val) > 3:
        val = val[0]
    return val


def _depth(x: Any) -> int:
    d = 0
    while isinstance(x, list):
        d += 1
        x = x[0] if x else None
    return d


def _is_pair(x: Any) -> bool:
    return (isinstance(x, list) and len(x) == 2
            and all(isinstance(r, list) and len(r) == 8 and all(not isinstance(v, list) for v in r) for r in x))


_RANK = {"zero_quaternion": 5, "non_finite": 4, "truncated": 3, "wrong_shape": 2}


def _eval_candidate(c: _Cand) -> tuple[str, np.ndarray | None, str, int]:
    """(status, actions, detail, n_kept) for one candidate."""
    if c.garbage:
        return "wrong_shape", None, "array contains non-numeric tokens", 0
    val = _squeeze(c.value)
    if c.closed:
        shp = _shape(val)
        if shp is not None and len(shp) == 3 and shp[1:] == (2, 8) and shp[0] >= 1:
            st, arr, det = _finish(np.asarray(val, dtype=np.float64))
            return st, arr, det, (0 if arr is None else arr.shape[0])
        return "wrong_shape", None, f"array of shape {_describe(val)}, expected (n, 2, 8)", 0
    # cut in the middle: keep the complete leading waypoints
    if _depth(val) < 3:
        return "truncated", None, "answer ended inside an array with no complete waypoint", 0
    rows = []
    for w in val:
        if _is_pair(w):
            rows.append(w)
        else:
            break
    # the last complete-looking pair may itself be still open when cut: only closed ones are lists of 8;
    # an open inner list has < 8 numbers and fails _is_pair
    if len(rows) < 2:
        return "truncated", None, f"answer cut inside the array after {len(rows)} complete waypoint(s) (< 2)", 0
    st, arr, det = _finish(np.asarray(rows, dtype=np.float64))
    if arr is None:
        return st, None, det, 0
    return "truncated", arr, f"answer cut inside the array: kept {arr.shape[0]} complete waypoint(s)", arr.shape[0]


def _merge_pairs(cands: list[_Cand]) -> list[_Cand]:
    """Top-level runs of (2, 8) pairs written without the outer brackets ("[[..],[..]],\n[[..],[..]]")
    become one (n, 2, 8) candidate, when adjacent (only separators between them); an unclosed
    candidate right after such a run is its cut-off tail."""
    out: list[_Cand] = []
    i = 0
    while i < len(cands):
        c = cands[i]
        if c.closed and not c.garbage and _is_pair(c.value):
            vals, j, closed = [c.value], i, True
            while j + 1 < len(cands) and cands[j + 1].start == cands[j].end and not cands[j + 1].garbage:
                nx = cands[j + 1]
                if nx.closed and _is_pair(nx.value):
                    vals.append(nx.value)
                    j += 1
                elif not nx.closed:
                    vals.append(nx.value)
                    j += 1
                    closed = False
                    break
                else:
                    break
            if len(vals) >= 2:
                out.append(_Cand(vals, False, closed, c.start, cands[j].end))
                i = j + 1
                continue
        out.append(c)
        i += 1
    return out


def _parse_tokens(toks: list) -> tuple[str, np.ndarray | None, str, int]:
    cands = _merge_pairs(_candidates(toks))
    if not cands:
        return "no_array", None, "no bracketed array in the answer", 0
    best: tuple | None = None
    first_deep: tuple | None = None  # the first failing (..., 2, 8)-deep array is the answer that failed
    for c in cands:
        st, arr, det, k = _eval_candidate(c)
        if arr is not None:
            return st, arr, det, k
        if first_deep is None and not c.garbage and _depth(_squeeze(c.value)) >= 3:
            first_deep = (st, arr, det, k)
        if best is None or _RANK.get(st, 0) > _RANK.get(best[0], 0):
            best = (st, arr, det, k)
    return first_deep or best


def parse_actions(text: Any, expected_waypoints: int | None = None, prefix: str | None = None) -> ParseResult:
    """Extract the first well-formed (n, 2, 8) action array from an LLM answer.  Never raises.

    Accepts prose around the array, markdown fences, JSON / Python / numpy-print list syntax (commas
    optional), exponents, unicode minus, a leading ``[[[`` opened by the prompt (a completion that
    starts inside the array: when the answer does not start with ``[``, or closes more brackets than
    it opens, the missing opening brackets are prepended; ``prefix`` overrides what is prepended),
    waypoints written without the outer brackets, extra leading singleton dimensions.
    Quaternions are normalised (a zero quaternion fails), gripper values snapped to 0/1 (>= 0.5 open).
    ``expected_waypoints``: only reported in ``detail`` when the count differs (not a failure).
    The raw answer is kept in ``ParseResult.raw``.
    """
    try:
        raw = text if isinstance(text, str) else ("" if text is None else str(text))
    except Exception:  # noqa: BLE001 - a broken __str__ must not escape
        raw = ""
    try:
        res = _parse(raw, prefix)
    except Exception as e:  # noqa: BLE001 - never raise on any input
        res = ParseResult(None, "no_array", f"parser error: {type(e).__name__}")
    res.raw = raw
    if res.actions is not None and expected_waypoints is not None and res.actions.shape[0] != int(expected_waypoints):
        note = f"{res.actions.shape[0]} waypoints, expected {int(expected_waypoints)}"
        res.detail = f"{res.detail}; {note}" if res.detail else note
    return res


_FENCE = re.compile(r"```[A-Za-z0-9_+-]*")
_STARTS_INSIDE = re.compile(r"\s*(?:[-+]?(?:\d|\.\d|nan|inf)|\])", re.IGNORECASE)


def _parse(raw: str, prefix: str | None) -> ParseResult:
    if not raw.strip():
        return ParseResult(None, "empty", "empty answer")
    t = raw.replace("\u2212", "-").replace("\u2013", "-")
    t = _FENCE.sub(" ", t)  # markdown code fences (``` / ```json / ```python)
    toks = _tokenize(t)
    # a completion continuing an opened "[[[": starts with a number, or closes more than it opens
    depth, min_depth = 0, 0
    for kind, _ in toks:
        if kind == _LB:
            depth += 1
        elif kind == _RB:
            depth -= 1
            min_depth = min(min_depth, depth)
    attempts = []
    if _STARTS_INSIDE.match(t):
        n_open = ANSWER_PREFIX.count("[") if prefix is None else prefix.count("[")
        # the answer starts inside the array: only this reading (fragments of a malformed array
        # must not be taken for an answer)
        attempts.append([(_LB, None)] * max(n_open, -min_depth) + toks)
    else:
        if min_depth < 0:
            attempts.append([(_LB, None)] * (-min_depth) + toks)
        attempts.append(toks)
    results = [_parse_tokens(a) for a in attempts]
    for st, arr, det, k in results:
        if arr is not None:
            return ParseResult(arr, st, det, k)
    st, arr, det, k = max(results, key=lambda r: _RANK.get(r[0], 0))
    if st == "no_array" and not any(kd == _NUM for kd, _ in toks):
        det = "no numbers in the answer"
    return ParseResult(None, st, det, 0)
