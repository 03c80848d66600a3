"""How far each LLM answer of a Table 3 run lies from the examples it was shown (issue 21's per-trial
diagnostic: does the model copy the nearest example, as the thesis saw GPT do?).

For every LLM row of `table3_trials` (or of the given Parquet files, each labelled by its file name):
the answer is parsed and read back in metres with the prompt's number format, and compared with each
example's action sequence resampled to the answer's length: mean gripper-position distance (mm, both
arms) and gripper-state agreement, the most similar example (the one the prompt puts last) first.
Run from the project root:

    python -m scripts.llm_answer_diagnostics --warehouse WH [--files A.parquet B.parquet --formats thesis compact]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from demoforge.lib.llm.number_format import get_number_format
from demoforge.lib.llm.prompting import ANSWER_PREFIX, order_by_similarity, parse_actions, resample_actions
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.tasks.table3 import LLM_STRATEGIES, _database


def diagnose(warehouse: str, rows: list[dict], number_format: str) -> list[dict]:
    fmt = get_number_format(number_format)
    out = []
    for r in rows:
        if r["strategy"] not in LLM_STRATEGIES:
            continue
        parsed = parse_actions(r["raw_answer"], prefix=ANSWER_PREFIX)
        d = {"scene": r["scene"], "strategy": r["strategy"], "parse": parsed.status, "success": r["success"],
             "failure": r["failure_reason"], "prompt_tokens": r["prompt_tokens"], "answer_tokens": r["answer_tokens"],
             "latency_s": r["latency_s"], "dist_mm": [], "gripper_agree": []}
        if parsed.ok:
            ans = fmt.decode_poses(parsed.actions) if fmt.name != "thesis" else parsed.actions
            db = _database(warehouse, r["task"], r["database"])
            pos = {int(i): k for k, i in enumerate(db["ids"])}
            acts = episode_actions(warehouse, r["task"], r["database"], list(r["example_ids"]))
            exs = [(db["keypoints"][pos[i]], db["initial"][pos[i]], acts[i]) for i in r["example_ids"]]
            for e in reversed(order_by_similarity(exs, np.asarray(r["query_keypoints"], float))):
                ref = resample_actions(e.actions, len(ans))
                d["dist_mm"].append(1000 * float(np.linalg.norm(ans[..., :3] - ref[..., :3], axis=-1).mean()))
                d["gripper_agree"].append(float(np.mean((ans[..., 7] >= 0.5) == (ref[..., 7] >= 0.5))))
        out.append(d)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--warehouse", required=True)
    ap.add_argument("--files", nargs="*", help="table3_trials Parquet files (default: the warehouse's table)")
    ap.add_argument("--formats", nargs="*", help="the number format of each file (default: thesis)")
    args = ap.parse_args()
    if args.files:
        sources = [(Path(f).stem, pq.read_table(f).to_pylist(), fmt)
                   for f, fmt in zip(args.files, args.formats or ["thesis"] * len(args.files))]
    else:
        from demoforge.schemas.catalog import query

        sources = [("table3_trials", query("SELECT * FROM table3_trials", args.warehouse).to_pylist(), "thesis")]
    print("| run | scene | strategy | parse | success | failure | prompt tokens | answer tokens | seconds "
          "| mean distance to each example, most similar first (mm) | gripper agreement with it |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, rows, fmt in sources:
        for d in diagnose(args.warehouse, rows, fmt):
            dist = ", ".join(f"{x:.0f}" for x in d["dist_mm"]) or "-"
            agree = ", ".join(f"{x:.0%}" for x in d["gripper_agree"]) or "-"
            print(f"| {label} | {d['scene']} | {d['strategy']} | {d['parse']} | {d['success']} | {d['failure'] or '-'} "
                  f"| {d['prompt_tokens']} | {d['answer_tokens']} | {d['latency_s']:.1f} | {dist} | {agree} |")


if __name__ == "__main__":
    main()
