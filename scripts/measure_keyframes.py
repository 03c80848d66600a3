"""Round trip of the action encodings in physics (issue 21 point 2): database episodes executed in
MuJoCo raw, keyframe-encoded -> decoded, and uniformly resampled to 20 waypoints -> upsampled.

The episodes (``--source``):

* ``warehouse`` (default): valid episodes of the databases a warehouse holds, exactly as the
  pipeline built them (``episodes`` / ``episode_steps``, e.g. after ``make evaluate`` or
  ``demoforge table3``): augmented from the ingested demonstration, with its per-frame jitter;
* ``scripted``: a database built in memory (``generate_episodes``) from the task library's scripted
  demonstration of ``--demo-seed`` (no perception noise).

Forms, each executed with ``demoforge.lib.sim.execute_many``:

* ``raw``: the episode's actions as stored;
* ``keyframes``: ``keyframe_actions`` with the task's settings (``Task.keyframes``: smoothing, then the
  bounded-error encoder: what the prompts write) -> ``decode_keyframes`` at the keyframes' own steps (how an
  answer of the same keyframes is executed);
* ``keyframes_unsmoothed``: the encoder alone at 5 mm / 0.05 rad (the earlier default);
* ``uniform20`` / ``uniform40``: ``resample_actions(.., n)`` -> ``tasks.llm_eval.upsample`` (the uniform
  prompts; 40 is the learned policy's default).

"lost" = episodes that succeed raw and fail in that form. Tokens are Gemma 3's (the embedded model's
tokenizer, vocabulary only; ``--approx-tokens`` for the one-per-digit estimate) of one action block in
each number format: what an answer costs.

    .venv/bin/python scripts/measure_keyframes.py --warehouse WH [--tasks pouring ...] [--episodes 50]
    .venv/bin/python scripts/measure_keyframes.py --sweep --warehouse WH   # keyframe counts only, no physics
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter

import numpy as np

from demoforge.lib.llm.number_format import get_number_format
from demoforge.lib.llm.prompting import approx_token_count, format_actions, resample_actions
from demoforge.lib.sim import execute_many
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.keyframes import (
    KeyframeSettings, decode_keyframes, encode_keyframes, keyframe_actions, reconstruction_error,
)
from demoforge.tasks.llm_eval import upsample

FORMS = ("raw", "keyframes", "keyframes_unsmoothed", "uniform20", "uniform40")
UNSMOOTHED = KeyframeSettings(0.005, 0.05, 0.0)
SWEEP = [KeyframeSettings(p, r, s) for s in (0.0, 1.0, 2.0, 3.0) for p, r in ((0.005, 0.05), (0.01, 0.1), (0.015, 0.15),
                                                                             (0.02, 0.2))]


def warehouse_episodes(warehouse: str, task: str, n: int, seed: int) -> tuple[list, str]:
    """n valid episodes (keypoints, actions) drawn at random from the warehouse's first database of task."""
    from demoforge.schemas.catalog import query
    from demoforge.schemas.reads.episodes import episode_actions

    dbs = query("SELECT take, count(*) AS n FROM episodes WHERE task = ? AND valid GROUP BY take ORDER BY take",
                warehouse, [task])
    if dbs.num_rows == 0:
        raise SystemExit(f"no valid episodes of {task} in {warehouse}: build a database first (demoforge augment)")
    take = dbs.column("take")[0].as_py()
    ep = query("SELECT episode_id, object_keypoints FROM episodes WHERE task = ? AND take = ? AND valid "
               "ORDER BY episode_id", warehouse, [task, take])
    ids_all = np.asarray(ep.column("episode_id").to_numpy())
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(ids_all), size=min(n, len(ids_all)), replace=False))
    kps = ep.column("object_keypoints").to_pylist()
    acts = episode_actions(warehouse, task, take, ids_all[pick])
    return [(np.asarray(kps[i], float), acts[int(ids_all[i])]) for i in pick], take


def scripted_episodes(task: str, n: int, demo_seed: int, seed: int) -> tuple[list, str]:
    from demoforge.lib.task_library import get_task
    from demoforge.lib.trajectories.augmentation import from_scripted_demo, generate_episodes

    spec = get_task(task)
    db = generate_episodes(from_scripted_demo(spec, spec.scripted_demo(demo_seed)), n=300, n_mirrored=150, seed=seed)
    valid = np.flatnonzero(db.valid)
    ids = np.sort(np.random.default_rng(seed).choice(valid, size=min(n, len(valid)), replace=False))
    acts = db.episode_actions(ids)
    return [(db.keypoints[i], acts[j][:db.lengths[i]]) for j, i in enumerate(ids)], f"scripted seed {demo_seed}"


class Tokens:
    """Tokens of a written action block: Gemma 3's tokenizer when the embedded model is installed."""

    def __init__(self, approx: bool):
        self.llm = None
        if not approx:
            try:
                from demoforge.lib.llm.local_backend import ensure_gguf
                import llama_cpp

                self.llm = llama_cpp.Llama(model_path=str(ensure_gguf()), vocab_only=True, verbose=False)
            except Exception as e:  # noqa: BLE001 - fall back to the estimate, and say so
                print(f"(Gemma tokenizer unavailable: {e}; approximate counts)", file=sys.stderr)
        self.kind = "gemma3" if self.llm else "approx"

    def __call__(self, actions: np.ndarray, number_format: str) -> int:
        fmt = get_number_format(number_format)
        text = format_actions(fmt.encode_poses(actions), fmt.precision(3))
        if self.llm is None:
            return approx_token_count(text)
        return len(self.llm.tokenize(text.encode(), add_bos=False, special=False))


def measure_task(task: str, episodes: list, workers: int, tokens: Tokens,
                 settings: KeyframeSettings, forms_run=FORMS) -> dict:
    forms = {f: [] for f in FORMS}
    counts = {f: [] for f in FORMS[1:]}
    block = {(f, nf): [] for f in FORMS[1:] for nf in ("thesis", "compact")}
    err_p, err_q = [], []
    for kp, a in episodes:
        kf, idx = keyframe_actions(a, settings)
        dec = decode_keyframes(kf, idx, len(a))
        dp, dq = reconstruction_error(a, dec)
        err_p.append(float(np.median(dp)))
        err_q.append(float(np.median(dq)))
        idx_u = encode_keyframes(a, UNSMOOTHED.pos_tol_m, UNSMOOTHED.rot_tol_rad)
        u20, u40 = resample_actions(a, 20), resample_actions(a, 40)
        written = {"keyframes": kf, "keyframes_unsmoothed": a[idx_u], "uniform20": u20, "uniform40": u40}
        forms["raw"].append((kp, a))
        forms["keyframes"].append((kp, dec))
        forms["keyframes_unsmoothed"].append((kp, decode_keyframes(a[idx_u], idx_u, len(a))))
        forms["uniform20"].append((kp, upsample(u20, len(a))))
        forms["uniform40"].append((kp, upsample(u40, len(a))))
        for f, w in written.items():
            counts[f].append(len(w))
            for nf in ("thesis", "compact"):
                block[(f, nf)].append(tokens(w, nf))
    out = {"task": task, "episodes": len(episodes), "mean_steps": float(np.mean([len(a) for _, a in episodes])),
           "keyframes": {f: float(np.mean(v)) for f, v in counts.items()},
           "keyframes_range": [int(min(counts["keyframes"])), int(max(counts["keyframes"]))],
           "block_tokens": {f"{f}/{nf}": float(np.mean(v)) for (f, nf), v in block.items()},
           "median_err_mm": 1000 * float(np.median(err_p)), "median_err_rad": float(np.median(err_q)), "forms": {}}
    oks = {}
    for f in forms_run:
        t0 = time.perf_counter()
        res = execute_many(task, forms[f], workers=workers)
        oks[f] = np.array([r.success for r in res])
        out["forms"][f] = {"success": int(oks[f].sum()), "n": len(res), "wall_s": time.perf_counter() - t0,
                           "failures": dict(Counter(str(r.failure) for r in res if not r.success))}
    for f in forms_run:
        out["forms"][f]["lost"] = int((oks["raw"] & ~oks[f]).sum()) if "raw" in oks else None
    return out


def sweep(task: str, episodes: list) -> list[dict]:
    """Keyframe counts and reconstruction errors against the raw steps for each SWEEP setting."""
    rows = []
    for s in SWEEP:
        n, e95 = [], []
        for _, a in episodes:
            kf, idx = keyframe_actions(a, s)
            dp, _ = reconstruction_error(a, decode_keyframes(kf, idx, len(a)))
            n.append(len(idx))
            e95.append(np.percentile(dp, 95))
        rows.append({"task": task, "pos_tol_mm": s.pos_tol_m * 1000, "rot_tol_rad": s.rot_tol_rad,
                     "sigma_steps": s.smooth_sigma_steps, "keyframes": float(np.mean(n)),
                     "p95_err_vs_raw_mm": 1000 * float(np.mean(e95))})
    return rows


def markdown(results: list[dict], token_kind: str) -> str:
    lines = ["| task | form | success | lost vs raw | failures | keyframes / waypoints | "
             f"tokens of one action block, thesis / compact ({token_kind}) |", "|---|---|---|---|---|---|---|"]
    for r in results:
        for f in FORMS:
            if f not in r["forms"]:
                continue
            s = r["forms"][f]
            if f == "raw":
                count, tok = f"{r['mean_steps']:.0f} steps", "-"
            else:
                count = f"{r['keyframes'][f]:.1f}"
                tok = f"{r['block_tokens'][f + '/thesis']:.0f} / {r['block_tokens'][f + '/compact']:.0f}"
            fails = ", ".join(f"{k} {v}" for k, v in sorted(s["failures"].items())) or "-"
            lines.append(f"| {r['task']} | {f} | {s['success']}/{s['n']} | {s['lost']} | {fails} | {count} | {tok} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["pouring"])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--source", choices=("warehouse", "scripted"), default="warehouse")
    ap.add_argument("--warehouse", default="warehouse", help="where the databases are (--source warehouse)")
    ap.add_argument("--demo-seed", type=int, default=0)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keyframes", nargs=3, type=float, metavar=("POS_TOL_M", "ROT_TOL_RAD", "SIGMA_STEPS"),
                    default=None, help="keyframe settings of the `keyframes` form (default: each task's, Task.keyframes)")
    ap.add_argument("--forms", nargs="+", choices=FORMS, default=list(FORMS), help="forms to execute")
    ap.add_argument("--sweep", action="store_true", help="only keyframe counts and errors for several settings")
    ap.add_argument("--approx-tokens", action="store_true", help="count tokens by the one-per-digit estimate")
    ap.add_argument("--json", default=None, help="also write the figures as JSON here")
    args = ap.parse_args(argv)
    results, sweeps = [], []
    tokens = None if args.sweep else Tokens(args.approx_tokens)
    for task in args.tasks:
        t0 = time.perf_counter()
        if args.source == "warehouse":
            eps, origin = warehouse_episodes(args.warehouse, task, args.episodes, args.seed)
        else:
            eps, origin = scripted_episodes(task, args.episodes, args.demo_seed, args.seed)
        if args.sweep:
            sweeps += sweep(task, eps)
            continue
        kfs = KeyframeSettings(*args.keyframes) if args.keyframes else get_task(task).keyframes
        r = measure_task(task, eps, args.workers, tokens, kfs, args.forms)
        r["keyframe_settings"] = [kfs.pos_tol_m, kfs.rot_tol_rad, kfs.smooth_sigma_steps]
        r.update(origin=origin, wall_s=time.perf_counter() - t0)
        print(f"{task}: {json.dumps(r)}", file=sys.stderr, flush=True)
        results.append(r)
    if args.sweep:
        print("| task | pos tol (mm) | rot tol (rad) | smoothing sigma (steps) | keyframes | p95 error vs raw (mm) |")
        print("|---|---|---|---|---|---|")
        for s in sweeps:
            print(f"| {s['task']} | {s['pos_tol_mm']:.0f} | {s['rot_tol_rad']:.2f} | {s['sigma_steps']:.0f} | "
                  f"{s['keyframes']:.1f} | {s['p95_err_vs_raw_mm']:.1f} |")
        return 0
    print(markdown(results, tokens.kind))
    for r in results:
        print(f"\n{r['task']} ({r['origin']}): {r['episodes']} episodes; keyframes {r['keyframes_range'][0]}-"
              f"{r['keyframes_range'][1]}, decoded vs raw median {r['median_err_mm']:.1f} mm / "
              f"{r['median_err_rad']:.3f} rad; {r['wall_s']:.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
