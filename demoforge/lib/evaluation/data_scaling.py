"""The data-scaling plot: a closed-loop policy's success against the number of episodes it was trained on,
per task, with Wilson 95 % intervals, and the LLM-free baselines on the same scenes as horizontal lines."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from demoforge.lib.evaluation.plots import _plt, _save


def plot_data_scaling(rows: Sequence[dict], out_png) -> Path | None:
    """rows: `report_data_scaling` rows (task, method, n_train_episodes, success_rate, wilson_low, wilson_high).
    One panel per task; None when there is no closed-loop row."""
    tasks = sorted({r["task"] for r in rows if r["method"] == "closed_loop"})
    if not tasks:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, len(tasks), figsize=(4.2 * len(tasks), 3.4), squeeze=False, sharey=True)
    for ax, task in zip(axes[0], tasks):
        own = [r for r in rows if r["task"] == task]
        cl = sorted((r for r in own if r["method"] == "closed_loop"), key=lambda r: r["n_train_episodes"])
        for robot in sorted({r["robot"] for r in cl}):
            pts = [r for r in cl if r["robot"] == robot]
            n = np.array([r["n_train_episodes"] for r in pts], float)
            p = np.array([r["success_rate"] for r in pts], float)
            lo = p - np.array([r["wilson_low"] for r in pts], float)
            hi = np.array([r["wilson_high"] for r in pts], float) - p
            ax.errorbar(n, p, yerr=[lo, hi], marker="o", capsize=3, label=f"closed loop ({robot})")
        for r, style in zip((r for r in own if r["method"] != "closed_loop"), ("--", ":", "-.")):
            ax.axhline(r["success_rate"], ls=style, color="gray", label=f"{r['method']} ({r['successes']}/{r['scenes']})")
        ax.set_xscale("log")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("training episodes")
        ax.set_title(task)
        ax.legend(fontsize=7, loc="upper left")
    axes[0][0].set_ylabel("success on held-out scenes")
    return _save(fig, out_png)


__all__ = ["plot_data_scaling"]
