"""Free vs structured (GBNF-constrained) greedy answers of the embedded Gemma 3 270M on 3 small real
prompts (tests/support/llm.py's real_prompts: 1 example each, 2-3 waypoints): parse status,
seconds, completion tokens.  Run from the project root:

    python -m scripts.measure_grammar [--max-tokens 400]   # -m: the project root on sys.path (tests/, demoforge)
"""

from __future__ import annotations

import argparse
import time

from demoforge.lib.llm import Sampling
from demoforge.lib.llm.local_backend import LocalBackend
from demoforge.lib.llm.prompting import parse_actions
from tests.support.llm import real_prompts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-tokens", type=int, default=400)
    args = ap.parse_args()
    b = LocalBackend(n_ctx=4096)
    b.llm  # load before timing
    print("| prompt | waypoints | prompt tokens | mode | parse | shape | seconds | completion tokens | finish |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, p in enumerate(real_prompts()):
        for structured in (False, True):
            s = Sampling(temperature=0.0, max_tokens=args.max_tokens, seed=0, stop=p.stop, structured=structured)
            t0 = time.perf_counter()
            c = b.complete(p, s)
            dt = time.perf_counter() - t0
            r = parse_actions(c.text, expected_waypoints=p.n_waypoints, prefix=p.answer_prefix)
            shape = "-" if r.actions is None else str(tuple(r.actions.shape))
            print(f"| {i} | {p.n_waypoints} | {c.prompt_tokens} | {'structured' if structured else 'free'} | "
                  f"{r.status} | {shape} | {dt:.1f} | {c.completion_tokens} | {c.finish_reason} |", flush=True)


if __name__ == "__main__":
    main()
