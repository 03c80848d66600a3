"""Rolling a policy out in a DemoforgeEnv: one episode from a reset to the environment's verdict.

A policy is any callable ``policy(state, environment_state, time_s) -> action`` over the export's
features (observation.state, observation.environment_state, the frame's timestamp), with an optional
``reset()`` called at each episode's start (demoforge.lib.policy.chunking.TemporalEnsemble is one)."""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from demoforge.envs.observation import ENV_STATE, STATE


def rollout(env, policy: Callable[[np.ndarray, np.ndarray, float], Any], seed: int | None = None,
            options: dict | None = None) -> dict:
    """{success, failure, detail, frames, seconds, clipped_steps} of one episode of `policy` in `env`
    (reset with seed and options). An invalid action (NaN) ends the episode as the environment records it
    (failure ``invalid_action``); nothing here raises for a policy's bad output but a wrong shape."""
    t0 = time.perf_counter()
    obs, info = env.reset(seed=seed, options=options)
    if hasattr(policy, "reset"):
        policy.reset()
    clipped = 0
    while True:
        action = policy(obs[STATE], obs[ENV_STATE], float(info["time_s"]))
        obs, _, terminated, truncated, info = env.step(np.asarray(action, np.float32))
        clipped += bool(info["action_clipped"])
        if terminated or truncated:
            break
    return {"success": bool(info["success"]), "failure": info["failure"] or "", "detail": str(info["detail"])[:500],
            "frames": int(info["frame"]), "seconds": time.perf_counter() - t0, "clipped_steps": clipped}


__all__ = ["rollout"]
