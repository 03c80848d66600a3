"""LeRobot's own statistics, written out as the reference the exports are compared with."""

import numpy as np


def reference_episode_quantiles(x: np.ndarray) -> dict:
    """LeRobot's RunningQuantileStats quantiles of one episode, written out per dimension as in
    lerobot/datasets/compute_stats.py (np.histogram, cumsum, searchsorted, linear in the bin)."""
    out = {}
    for q, key in zip((0.01, 0.10, 0.50, 0.90, 0.99), ("q01", "q10", "q50", "q90", "q99")):
        vals = []
        for d in range(x.shape[1]):
            edges = np.linspace(x[:, d].min() - 1e-10, x[:, d].max() + 1e-10, 5001)
            cs = np.cumsum(np.histogram(x[:, d], bins=edges)[0])
            target = q * len(x)
            i = int(np.searchsorted(cs, target))
            if i == 0:
                vals.append(edges[0])
                continue
            before, inside = cs[i - 1], cs[i] - cs[i - 1]
            vals.append(edges[i] if inside == 0 else edges[i] + (target - before) / inside * (edges[i + 1] - edges[i]))
        out[key] = np.array(vals)
    return out

