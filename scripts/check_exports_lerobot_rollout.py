"""`make check-exports`, the real client closed-loop: LeRobot's ACT, trained by `lerobot-train` on demoforge's
joint-space export, rolled out step by step in demoforge's Gymnasium environment of the same task and robot.
Runs in .venv-lerobot (Python 3.12, lerobot) with demoforge on PYTHONPATH and only the environment's own
dependencies installed there (mujoco, mink, qpsolvers, daqp, scipy; gymnasium and numpy come with lerobot):
demoforge.envs imports no Prefect, DuckDB, Open3D or OpenCV.

    .venv-lerobot/bin/python scripts/check_exports_lerobot_rollout.py PRETRAINED_MODEL_DIR [--scenes N]

The scenes: `reset(seed=s)` under the thesis protocol of the scripted demonstration (seed 1) that the sample
warehouse's database augments (scripts/check_exports_sample.py), seeds 1,000,000 + i (no database uses them).
Prints one CHECK line (JSON) with the success rate and the failures, as scripts/check_exports.sh collects them.

The export's gripper columns are the demonstrated opening; the robot check closes each hand 0.3 s (`lead`
frames) before it (DemoforgeEnv.replay_actions). A policy imitating the export predicts the demonstrated
opening, so each step here closes a hand when the newest predicted chunk closes it within the next `lead`
frames: the same conversion, applied to the prediction. The joints: ACT's own temporal ensembling.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TASK, DEMO_SEED, SCENE_SEED_BASE = "pouring", 1, 1_000_000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pretrained", help="lerobot-train's checkpoints/last/pretrained_model folder")
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--max-steps", type=int, default=600)
    args = ap.parse_args()
    t0 = time.perf_counter()
    import torch
    import gymnasium
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    import demoforge.envs  # noqa: F401  (registers demoforge/<task>-<robot>-v0)
    from demoforge.envs.observation import ENV_STATE, STATE

    config = ACTConfig.from_pretrained(args.pretrained)
    config.n_action_steps, config.temporal_ensemble_coeff = 1, 0.01  # ACT's temporal ensembling, closed loop
    config.device = "cpu"
    policy = ACTPolicy.from_pretrained(args.pretrained, config=config)
    policy.eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=args.pretrained)
    env = gymnasium.make(f"demoforge/{TASK}-aloha2f140-v0", protocol="thesis", demo_seed=DEMO_SEED,
                         max_steps=args.max_steps, check_success_every=15).unwrapped
    lead, grippers = env.stepper.lead, env.gripper_cols
    outcomes = Counter()
    for i in range(args.scenes):
        obs, info = env.reset(seed=SCENE_SEED_BASE + i)
        policy.reset()
        while True:
            batch = {STATE: torch.as_tensor(obs[STATE])[None], ENV_STATE: torch.as_tensor(obs[ENV_STATE])[None]}
            with torch.inference_mode():
                chunk = policy.predict_action_chunk(pre(batch))                 # (1, chunk, 14), normalised
                action = np.asarray(post(policy.temporal_ensembler.update(chunk)), np.float32).reshape(-1)
                ahead = np.asarray(post(chunk[0, : lead + 1]), np.float32)     # the next lead + 1 frames
            for g in grippers:
                action[g] = 0.0 if (ahead[:, g] < 0.5).any() else 1.0
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        outcomes["success" if info["success"] else info["failure"]] += 1
    n_ok = outcomes["success"]
    detail = (f"{n_ok}/{args.scenes} held-out scenes succeed ({', '.join(f'{k} {v}' for k, v in outcomes.most_common())}); "
              f"{time.perf_counter() - t0:.0f}s")
    print("CHECK " + json.dumps({"check": "lerobot ACT (trained on the joint-space export) in demoforge's Gymnasium "
                                          "environment", "ok": True, "detail": detail, "successes": n_ok,
                                 "scenes": args.scenes}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
