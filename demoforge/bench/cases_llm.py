"""Benchmark cases of the embedded LLM (registered in demoforge/bench/registry.py).

trial   fast     = one Table 3 "3 Retrieved" trial's prompt and greedy structured answer with the local
                   backend's fast decoder (demoforge.lib.llm.structured_decoding) on the reduced-
                   vocabulary model (demoforge.lib.llm.reduced_vocab).
        baseline = the same prompts answered under llama.cpp's GBNF grammar sampler (the backend's
                   decoder until 2026-11-25), or (the "vocabulary" case) by the same fast decoder on
                   the full model. Both give the same text (checked).
        Prompts: a pouring database (the scripted demonstration augmented, 2,000 episodes), query
        scenes drawn from the same sampler with another seed, their three nearest episodes as
        examples written as keyframes (pouring's settings), the thesis's and the compact number format. Seconds per
        trial = seconds / size.
tokens  decoding alone: a one-example compact prompt evaluated once (its state restored before each
        answer), the answer cut at `size` tokens; items per second = answer tokens per second.
The model is loaded before timing. No case when llama-cpp-python is not installed.
"""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib.llm import Sampling
from demoforge.lib.llm.grammar import MAX_ROWS, structured_grammar
from demoforge.lib.llm.local_backend import LocalBackend
from demoforge.lib.llm.prompting import build_prompt, order_by_similarity
from demoforge.lib.llm.structured_decoding import action_tokens, greedy_structured, language_for_prompt
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
from demoforge.lib.trajectories.retrieval import KeypointIndex


def _prompts(n: int, number_format: str, n_examples: int = 3):
    spec = get_task("pouring")
    source = from_scripted_demo(spec, spec.scripted_demo(0))
    db = generate_episodes(source, n=1_999, n_mirrored=999, seed=0, materialize=True)
    queries = generate_episodes(source, n=n, n_mirrored=0, seed=12_345, materialize=True)
    index = KeypointIndex(db.keypoints)
    prompts = []
    for q in range(n):
        kp = queries.keypoints[q + 1]  # episode 0 is the unmoved demonstration
        top = np.asarray(index.query(kp, k=n_examples).ids).ravel()
        examples = [(db.keypoints[i], db.initial[i], db.actions[i, : db.lengths[i]]) for i in top]
        prompts.append(build_prompt(order_by_similarity(examples, kp), kp, queries.initial[q + 1],
                                    number_format=number_format, keyframes=spec.keyframes))
    return prompts


def _answer_setup(prompts, baseline: str = "gbnf"):
    fast_backend, base_backend = LocalBackend(), LocalBackend(structured_decoder=baseline)
    fast_backend.reduced_model()  # load both models (once per process; the reduced one built once) untimed

    def answer(backend):
        def go():
            out = []
            for p in prompts:
                s = Sampling(temperature=0.0, max_tokens=p.answer_tokens_estimate, seed=0,
                             stop=tuple(p.stop), structured=True)
                out.append(backend.complete(p, s).text)
            return out
        return go

    return answer(fast_backend), answer(base_backend)


def _same_text(fast: list[str], baseline: list[str]) -> None:
    if fast != baseline:
        raise AssertionError("the fast decoder's answers differ from the baseline's")


def cases(quick: bool) -> list[BenchCase]:
    try:
        import llama_cpp  # noqa: F401
    except ImportError:
        return []
    n = 1 if quick else 2
    out = []
    for fmt in ("thesis", "compact"):
        cache: dict = {}

        def setup(size: int, fmt=fmt, cache=cache):
            if size not in cache:
                cache[size] = _prompts(size, fmt)
            return _answer_setup(cache[size])

        out.append(BenchCase("llm", f"Table 3 trial ({fmt} numbers, 3 examples, keyframes)", n, "trials",
                             "llama.cpp GBNF grammar sampler", setup, check=_same_text, repeats=1))
    vocab_cache: dict = {}

    def vocab_setup(size: int, cache=vocab_cache):
        if size not in cache:
            cache[size] = _prompts(size, "compact")
        return _answer_setup(cache[size], baseline="fast-full")

    out.append(BenchCase("llm", "Table 3 trial (compact numbers), reduced vs full vocabulary", n, "trials",
                         "fast decoder on the full 262k vocabulary", vocab_setup, check=_same_text, repeats=1))
    n_tokens = 128 if quick else 512
    out.append(BenchCase("llm", "structured answer tokens, prompt already evaluated", n_tokens, "answer tokens",
                         "llama.cpp GBNF grammar sampler", _tokens_setup, check=_same_text, repeats=1))
    return out


def _tokens_setup(size: int):
    """Decoding alone: the prompt is evaluated once, its state saved and restored before each answer,
    so both decoders re-evaluate only the prompt's last token (for its logits) and then answer."""
    prompt = _prompts(1, "compact", n_examples=1)[0]  # its answer is ~1,000 tokens: cut at size
    llm = LocalBackend().llm
    action_tokens(llm)  # the vocabulary scan (~0.6 s, once per model) outside the timed calls
    tokens = llm.tokenize(prompt.text.encode("utf-8"), add_bos=True, special=True)
    llm.reset()
    llm.eval(tokens)
    state = llm.save_state()

    def fast():
        llm.load_state(state)
        r = greedy_structured(llm, tokens, language_for_prompt(prompt, prompt.text, MAX_ROWS), size, reuse_prefix=True)
        return [r.text]

    def baseline():
        llm.load_state(state)
        out = llm.create_completion(prompt=prompt.text, max_tokens=size, temperature=0.0, seed=0,
                                    grammar=structured_grammar(prompt, prompt.text))
        return [out["choices"][0]["text"]]

    return fast, baseline
