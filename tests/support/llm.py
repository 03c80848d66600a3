"""Small LLM inputs the tests share: hand-made examples and prompts, the GBNF grammar as a regex, and the
mark for tests that need the embedded model's runtime (llama-cpp-python)."""

from __future__ import annotations

import importlib.util
import json
import re

import numpy as np
import pytest

from demoforge.lib.llm.prompting import Example, build_prompt

_HAVE_LLAMA = importlib.util.find_spec("llama_cpp") is not None
needs_llama = pytest.mark.skipif(not _HAVE_LLAMA, reason="llama_cpp (llama-cpp-python) is not importable: "
                                 "install requirements/llm.txt (scripts/setup_llm.sh)")


def demo(shift: float = 0.0, n: int = 5, seed: int = 0):
    """A small synthetic example (keypoints, initial poses, actions) with a gripper closing midway."""
    rng = np.random.default_rng(seed)
    kp = rng.uniform(-0.3, 0.3, size=(11, 3)) + shift
    acts = np.zeros((n, 2, 8))
    acts[:, :, :3] = np.linspace(0, 0.1, n)[:, None, None] + np.array([[-0.2, 0.1, 0.15], [0.2, 0.1, 0.15]]) + shift
    acts[:, :, 6] = 1.0
    acts[:, :, 7] = 1.0
    acts[n // 2:, 1, 7] = 0.0
    return kp, acts[0], acts


def real_prompts():
    """Three short real prompts (1 example each, 2-3 waypoints): uniform and keyframe encodings."""
    a, b, c = demo(0.0, seed=0), demo(0.05, seed=1), demo(-0.04, n=7, seed=2)
    return [build_prompt([a], a[0] + 0.01, a[1], n_waypoints=2),
            build_prompt([b], b[0] - 0.02, b[1], n_waypoints=3),
            build_prompt([c], c[0] + 0.02, c[1], n_waypoints=2)]


_GBNF_TOKEN = re.compile(r'"(?:\\.|[^"\\])*"|\[[^\]]*\]|[A-Za-z_]+|\{\d+(?:,\d+)?\}|[()|?*+]|\s+')


def gbnf_regex(grammar: str) -> re.Pattern:
    """A non-recursive GBNF grammar's language as a regex: the grammar itself is checked, not a copy.
    Quantifiers are possessive (``?+``, ``{m,n}+``): for the action-list grammar the same language (a
    number is always followed by a non-digit, a row by ',' or ']'), without exponential backtracking
    on a string it rejects (a digit could otherwise sit in any of the optional ``[0-9]?`` slots)."""
    rules = dict(line.split(" ::= ", 1) for line in grammar.strip().splitlines())
    rules = {k.strip(): v for k, v in rules.items()}

    def conv(name: str) -> str:
        out = []
        for t in _GBNF_TOKEN.findall(rules[name]):
            if t.isspace():
                continue
            if t.startswith('"'):
                out.append(re.escape(json.loads(t)))
            elif t[0].isalpha() or t[0] == "_":
                out.append(f"(?:{conv(t)})")
            elif t == "(":
                out.append("(?:")  # capturing groups under possessive quantifiers upset Python's re
            elif t == "?" or t.startswith("{"):
                out.append(t + "+")
            else:
                out.append(t)
        return "".join(out)

    return re.compile(conv("root"))


def _quat_yaw(theta: float) -> list[float]:
    return [0.0, 0.0, float(np.sin(theta / 2)), float(np.cos(theta / 2))]


def hand_episode(shift: float, n: int = 9) -> Example:
    """A pick-and-pour-like episode: left arm holds still, right arm approaches, closes at step 3,
    lifts, opens at step 7; the left arm closes at step 2.  Keypoints: 11 points on two objects."""
    kp = np.array([[0.30 + shift, 0.10, 0.02 * i] for i in range(5)]
                  + [[-0.20 + shift, 0.25 + 0.01 * i, 0.05] for i in range(6)])
    acts = np.zeros((n, 2, 8))
    for t in range(n):
        u = t / (n - 1)
        acts[t, 0, :3] = [-0.25 + shift, 0.12, 0.15]
        acts[t, 0, 3:7] = _quat_yaw(0.5)
        acts[t, 0, 7] = 1.0 if t < 2 else 0.0
        acts[t, 1, :3] = [0.20 + shift + 0.1 * u, 0.05 + 0.05 * u, 0.18 - 0.1 * u]
        acts[t, 1, 3:7] = _quat_yaw(-0.3 + 0.6 * u)
        acts[t, 1, 7] = 0.0 if 3 <= t < 7 else 1.0
    return Example(kp, acts[0].copy(), acts)


def random_episode(rng, n, changes_left=(), changes_right=()):
    a = np.zeros((n, 2, 8))
    a[:, :, :3] = np.cumsum(rng.normal(scale=0.01, size=(n, 2, 3)), axis=0)
    q = rng.normal(size=(n, 2, 4))
    a[:, :, 3:7] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    for arm, ch in ((0, changes_left), (1, changes_right)):
        g = 1.0
        for t in range(n):
            if t in ch:
                g = 1.0 - g
            a[t, arm, 7] = g
    return a

