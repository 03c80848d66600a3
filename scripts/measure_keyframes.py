"""Round trip of the action encodings in physics (issue 21 point 2): database episodes executed in
MuJoCo raw, keyframe-encoded -> decoded, and uniformly resampled to 20 / 40 waypoints -> upsampled.

Per task: a demonstration -> an augmented
database in memory (``generate_episodes``, as `demoforge augment` builds it: translated and mirrored
episodes) -> ``--episodes`` valid episodes drawn at random -> each executed with
``demoforge.lib.sim.execute(task, keypoints, actions)`` in five forms:

The demonstration (``--source``): ``scripted``, the task library's scripted demo of seed
``--demo-seed`` (the ground truth a `demoforge synth` take of that seed is rendered from, no
perception noise); or ``ingested``, that synthetic take rendered (into ``--work``, if missing) and
ingested with the simulated detector (``flows.ingest.ingest_take``), read back as the augmentation
reads it (``tasks.augment.load_demo_source``): the trajectory with the ingest's noise.

* ``raw``: the episode's actions as stored;
* ``keyframes``: ``encode_keyframes`` (5 mm, 0.05 rad, gripper instants; what the prompts write) ->
  ``decode_keyframes`` at the keyframes' own steps;
* ``keyframes+boundaries``: the same with the plan's run starts (motion/skill boundaries) kept;
* ``keyframes_coarse``: 30 mm, 0.3 rad instead of 5 mm, 0.05 rad (how much margin is there);
* ``uniform20`` / ``uniform40``: ``resample_actions`` -> ``tasks.llm_eval.upsample`` (today's
  uniform prompts and their answers' decoding).

Tokens (``approx_token_count``, Gemma-like: one per digit): one example's action block (what an
answer costs), and a whole 3-example prompt (the episode and its two nearest
database neighbours by keypoint MSE, ordered most similar last, the query the episode's own scene),
mean over the episodes, per encoding.

    .venv/bin/python scripts/measure_keyframes.py [--tasks pouring trash_in_bin] [--episodes 50]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter

import numpy as np

from demoforge.lib.llm.prompting import (
    approx_token_count, build_prompt, format_actions, order_by_similarity, resample_actions,
)
from demoforge.lib.sim import execute_many
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes
from demoforge.lib.trajectories.keyframes import decode_keyframes, encode_keyframes, reconstruction_error
from demoforge.tasks.llm_eval import upsample

FORMS = ("raw", "keyframes", "keyframes+boundaries", "keyframes_coarse", "uniform20", "uniform40")
COARSE = (0.03, 0.3)  # m, rad: a coarser tolerance, to see how much margin the default has


def _group(db, i):
    return next(g for g in db.groups if g.row0 <= i < g.row1)


def ingested_source(task: str, demo_seed: int, work: str):
    """The synthetic take of (task, demo_seed) rendered and ingested into work/, as a DemoSource."""
    from pathlib import Path

    from demoforge.flows.ingest import ingest_take
    from demoforge.lib.synth.take import generate_take
    from demoforge.tasks.augment import load_demo_source

    root = Path(work)
    take = root / "takes" / f"synth_{task}_s{demo_seed:04d}"
    if not (take / "take.json").is_file():  # written last
        generate_take(task, demo_seed, False, take, video=False)
    warehouse = root / "warehouse"
    warehouse.mkdir(parents=True, exist_ok=True)
    ingest_take(str(take), str(warehouse), show_progress=False)
    return load_demo_source(take.name, task, str(warehouse))


def measure_task(task: str, n_episodes: int, n_database: int, demo_seed: int, seed: int, workers: int,
                 source: str = "scripted", work: str = "/tmp/measure_keyframes") -> dict:
    spec = get_task(task)
    if source == "ingested":
        src = ingested_source(task, demo_seed, work)
    else:
        src = from_scripted_demo(spec, spec.scripted_demo(demo_seed))
    db = generate_episodes(src, n=n_database, n_mirrored=n_database // 2, seed=seed)
    valid = np.flatnonzero(db.valid)
    rng = np.random.default_rng(seed)
    ids = np.sort(rng.choice(valid, size=min(n_episodes, len(valid)), replace=False))
    acts = db.episode_actions(ids)
    episodes = {f: [] for f in FORMS}
    n_kf, n_kfb, n_kfc, err_p, err_q = [], [], [], [], []
    tokens = {"keyframes": [], "uniform20": [], "uniform40": []}
    block = {"keyframes": [], "uniform20": [], "uniform40": []}  # one action block: what an answer costs
    for j, i in enumerate(ids):
        a = acts[j][:db.lengths[i]]
        kp = db.keypoints[i]
        idx = encode_keyframes(a)
        bounds = sorted({r.out0 for r in _group(db, i).plan.runs})
        idx_b = encode_keyframes(a, boundaries=bounds)
        dec = decode_keyframes(a[idx], idx, len(a))
        dp, dq = reconstruction_error(a, dec)
        n_kf.append(len(idx))
        n_kfb.append(len(idx_b))
        err_p.append(dp.max())
        err_q.append(dq.max())
        block["keyframes"].append(approx_token_count(format_actions(a[idx])))
        for m in (20, 40):
            block[f"uniform{m}"].append(approx_token_count(format_actions(resample_actions(a, m))))
        episodes["raw"].append((kp, a))
        episodes["keyframes"].append((kp, dec))
        episodes["keyframes+boundaries"].append((kp, decode_keyframes(a[idx_b], idx_b, len(a))))
        idx_c = encode_keyframes(a, *COARSE)
        n_kfc.append(len(idx_c))
        episodes["keyframes_coarse"].append((kp, decode_keyframes(a[idx_c], idx_c, len(a))))
        for m in (20, 40):
            episodes[f"uniform{m}"].append((kp, upsample(resample_actions(a, m), len(a))))
        # a 3-example prompt: the episode and its two nearest neighbours, the query its own scene
        d = np.mean(np.sum((db.keypoints[valid] - kp) ** 2, axis=-1), axis=-1)
        near = [int(x) for x in valid[np.argsort(d, kind="stable")[:3]]]
        nacts = db.episode_actions(near)
        exs = order_by_similarity([(db.keypoints[k], db.initial[k], nacts[r][:db.lengths[k]])
                                   for r, k in enumerate(near)], kp)
        tokens["keyframes"].append(approx_token_count(build_prompt(exs, kp, db.initial[i]).text))
        for m in (20, 40):
            tokens[f"uniform{m}"].append(approx_token_count(build_prompt(exs, kp, db.initial[i], n_waypoints=m).text))
    out = {"task": task, "source": source, "episodes": int(len(ids)), "database": int(len(db)), "valid": int(len(valid)),
           "mean_steps": float(np.mean(db.lengths[ids])), "mean_keyframes": float(np.mean(n_kf)),
           "mean_keyframes_boundaries": float(np.mean(n_kfb)), "mean_keyframes_coarse": float(np.mean(n_kfc)), "max_pos_err_m": float(np.max(err_p)),
           "max_rot_err_rad": float(np.max(err_q)),
           "prompt_tokens": {k: float(np.mean(v)) for k, v in tokens.items()},
           "block_tokens": {k: float(np.mean(v)) for k, v in block.items()}, "forms": {}}
    for f in FORMS:
        t0 = time.perf_counter()
        res = execute_many(task, episodes[f], workers=workers)
        ok = np.array([r.success for r in res])
        out["forms"][f] = {"success": int(ok.sum()), "n": int(len(ok)),
                           "failures": dict(Counter(str(r.failure) for r in res if not r.success)),
                           "wall_s": time.perf_counter() - t0,
                           # episodes that succeed raw but fail in this form
                           "lost": None}
        out["forms"][f]["_ok"] = ok
    raw_ok = out["forms"]["raw"]["_ok"]
    for f in FORMS:
        ok = out["forms"][f].pop("_ok")
        out["forms"][f]["lost"] = int((raw_ok & ~ok).sum())
    return out


def markdown(results: list[dict]) -> str:
    lines = ["| task | form | success | lost vs raw | failures | keyframes / waypoints | prompt tokens (3 examples) "
             "| tokens of one action block |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        for f in FORMS:
            s = r["forms"][f]
            if f == "raw":
                count, tok, blk = f"{r['mean_steps']:.0f} steps", "-", "-"
            elif f == "keyframes":
                count, tok = f"{r['mean_keyframes']:.1f}", f"{r['prompt_tokens']['keyframes']:.0f}"
                blk = f"{r['block_tokens']['keyframes']:.0f}"
            elif f == "keyframes+boundaries":
                count, tok, blk = f"{r['mean_keyframes_boundaries']:.1f}", "-", "-"
            elif f == "keyframes_coarse":
                count, tok, blk = f"{r['mean_keyframes_coarse']:.1f}", "-", "-"
            else:
                count, tok, blk = f[7:], f"{r['prompt_tokens'][f]:.0f}", f"{r['block_tokens'][f]:.0f}"
            fails = ", ".join(f"{k} {v}" for k, v in sorted(s["failures"].items())) or "-"
            lines.append(f"| {r['task']} | {f} | {s['success']}/{s['n']} | {s['lost']} | {fails} | {count} | {tok} | {blk} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["pouring", "trash_in_bin"])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--database", type=int, default=300, help="augmented episodes in the database")
    ap.add_argument("--demo-seed", type=int, default=0)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--source", choices=("scripted", "ingested"), default="scripted")
    ap.add_argument("--work", default="/tmp/measure_keyframes", help="takes and warehouse of --source ingested")
    ap.add_argument("--json", default=None, help="also write the figures as JSON here")
    args = ap.parse_args(argv)
    results = []
    for task in args.tasks:
        t0 = time.perf_counter()
        r = measure_task(task, args.episodes, args.database, args.demo_seed, args.seed, args.workers, args.source,
                         args.work)
        r["wall_s"] = time.perf_counter() - t0
        print(f"{task}: {json.dumps(r)}", file=sys.stderr, flush=True)
        results.append(r)
    print(markdown(results))
    for r in results:
        print(f"\n{r['task']} ({r['source']}): {r['episodes']} of {r['valid']} valid episodes (database {r['database']}), "
              f"keyframe reconstruction max {r['max_pos_err_m'] * 1000:.2f} mm / {r['max_rot_err_rad']:.4f} rad, "
              f"{r['wall_s']:.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
