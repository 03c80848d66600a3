"""The report's plots of the episode databases, as PNG files (matplotlib, Agg backend: no display).

- :func:`plot_trajectories`: both grippers' paths, the demonstration against augmented episodes;
- :func:`plot_workspace_coverage`: where the grippers go over all episodes (top view, per arm);
- :func:`plot_success_map`: robot success over the objects' placements.

Inputs are arrays in the DESIGN's conventions (world = table frame, m; poses ``[x, y, z, qx, qy,
qz, qw, g]``, arm 0 = left). Each function writes atomically and returns the numbers it drew.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

ARM_COLORS = ("tab:blue", "tab:orange")
ARM_NAMES = ("left", "right")


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: str | os.PathLike) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=".png", dir=out.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        _plt().close(fig)
    return out


def _check_poses(a: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(a, np.float64)
    if a.ndim != 3 or a.shape[1:] != (2, 8):
        raise ValueError(f"{what} must be (steps, 2, 8) gripper poses, got {a.shape}")
    return a


def plot_trajectories(original: np.ndarray, augmented: list[np.ndarray], out: str | os.PathLike, *,
                      keypoints: np.ndarray | None = None, workspace: np.ndarray | None = None,
                      title: str = "") -> dict:
    """Top view (x, y) and height over time of both grippers: the demonstration bold, ``augmented``
    episodes thin. keypoints: (11, 3) of the demonstration's scene (drawn as crosses)."""
    plt = _plt()
    original = _check_poses(original, "original")
    augmented = [_check_poses(a, f"augmented[{i}]") for i, a in enumerate(augmented)]
    fig, (ax_xy, ax_z) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1, 1.3]})
    for arm in (0, 1):
        for a in augmented:
            ax_xy.plot(a[:, arm, 0], a[:, arm, 1], color=ARM_COLORS[arm], lw=0.6, alpha=0.25)
            ax_z.plot(np.arange(len(a)) / 30.0, a[:, arm, 2], color=ARM_COLORS[arm], lw=0.6, alpha=0.25)
        ax_xy.plot(original[:, arm, 0], original[:, arm, 1], color="k", lw=2.2)
        ax_xy.plot(original[:, arm, 0], original[:, arm, 1], color=ARM_COLORS[arm], lw=1.4,
                   label=f"{ARM_NAMES[arm]} arm, demonstration")
        ax_xy.plot(*original[0, arm, :2], "o", color=ARM_COLORS[arm], mec="k")
        ax_z.plot(np.arange(len(original)) / 30.0, original[:, arm, 2], color=ARM_COLORS[arm], lw=2,
                  label=f"{ARM_NAMES[arm]} arm, demonstration")
    if keypoints is not None:
        kp = np.asarray(keypoints)
        ax_xy.plot(kp[:, 0], kp[:, 1], "kx", ms=6, label="object keypoints (demonstration)")
    if workspace is not None:
        (x0, y0), (x1, y1) = np.asarray(workspace)[0, :2], np.asarray(workspace)[1, :2]
        ax_xy.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", color="grey",
                                      label="workspace"))
    ax_xy.plot([], [], color="grey", lw=0.6, alpha=0.6, label=f"{len(augmented)} augmented episodes")
    ax_xy.set_xlabel("x (m, robot's right)")
    ax_xy.set_ylabel("y (m, away from the robot)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.set_title("top view")
    ax_xy.legend(fontsize=7, loc="best")
    ax_z.set_xlabel("time (s)")
    ax_z.set_ylabel("z (m above the table)")
    ax_z.set_title("gripper height")
    if title:
        fig.suptitle(title)
    _save(fig, out)
    return {"augmented": len(augmented), "steps": len(original)}


def coverage_grid(positions: np.ndarray, workspace: np.ndarray | None = None, cell: float = 0.02
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-arm top-view sample counts (2, nx, ny) over ``cell``-sized bins of the workspace's x-y box
    (of the data's box without one), and the bin edges in x and y. Non-finite samples are dropped."""
    p = np.asarray(positions, np.float64)
    if p.ndim != 3 or p.shape[1:] != (2, 3):
        raise ValueError(f"positions must be (samples, 2, 3), got {p.shape}")
    p = p[np.isfinite(p).all(axis=(1, 2))]
    if len(p) == 0:
        raise ValueError("no finite gripper positions to plot")
    if workspace is None:
        lo, hi = p[..., :2].reshape(-1, 2).min(0), p[..., :2].reshape(-1, 2).max(0)
    else:
        lo, hi = np.asarray(workspace)[0, :2], np.asarray(workspace)[1, :2]
    n = np.maximum(np.ceil((hi - lo) / cell - 1e-9).astype(int), 1)  # whole cells covering the box
    ex = lo[0] + cell * np.arange(n[0] + 1)
    ey = lo[1] + cell * np.arange(n[1] + 1)
    h = np.stack([np.histogram2d(p[:, a, 0], p[:, a, 1], bins=[ex, ey])[0] for a in (0, 1)])
    return h, ex, ey


def plot_workspace_coverage(positions: np.ndarray, out: str | os.PathLike, *, n_episodes: int | None = None,
                            workspace: np.ndarray | None = None, cell: float = 0.02, title: str = "") -> dict:
    """Top-view density of gripper positions (samples, 2, 3) per arm, log scale, over ``cell``-sized
    bins; returns the fraction of the workspace's cells each arm visits."""
    plt = _plt()
    from matplotlib.colors import LogNorm

    hist, ex, ey = coverage_grid(positions, workspace, cell)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    covered = {}
    for arm, ax in enumerate(axes):
        h = hist[arm]
        covered[ARM_NAMES[arm]] = float((h > 0).mean())
        im = ax.imshow(np.where(h > 0, h, np.nan).T, origin="lower", extent=(ex[0], ex[-1], ey[0], ey[-1]),
                       norm=LogNorm(vmin=1, vmax=max(h.max(), 2)), cmap="viridis", aspect="equal")
        ax.set_title(f"{ARM_NAMES[arm]} gripper: {100 * covered[ARM_NAMES[arm]]:.0f} % of "
                     f"{cell * 100:.0f} cm cells visited")
        ax.set_xlabel("x (m)")
        fig.colorbar(im, ax=ax, shrink=0.8, label="samples per cell")
    axes[0].set_ylabel("y (m)")
    sup = title or "Workspace coverage"
    if n_episodes is not None:
        sup += f" ({n_episodes:,} episodes, {int(hist[0].sum()):,} samples)"
    fig.suptitle(sup)
    _save(fig, out)
    return {"samples": int(hist[0].sum()), "covered_fraction": covered}


def plot_success_map(object_xy: np.ndarray, success: np.ndarray, out: str | os.PathLike, *,
                     object_names: list[str] | None = None, region: np.ndarray | None = None, bins: int = 6,
                     title: str = "") -> dict:
    """Success over the placements of each object: (N, n_objects, 2) object positions (x, y) per
    episode, (N,) robot success. Cells show the success rate of the episodes that fall in them
    (grey: none), dots the episodes (filled = success)."""
    plt = _plt()
    xy = np.asarray(object_xy, np.float64)
    ok = np.asarray(success, bool)
    if xy.ndim != 3 or xy.shape[2] != 2 or len(ok) != len(xy):
        raise ValueError(f"object_xy must be (episodes, objects, 2) and success (episodes,), got {xy.shape}, "
                         f"{ok.shape}")
    if len(xy) == 0:
        raise ValueError("no simulated episodes to map: run `demoforge simulate --task T` first")
    n_obj = xy.shape[1]
    names = object_names or [f"object {i}" for i in range(n_obj)]
    fig, axes = plt.subplots(1, n_obj, figsize=(6 * n_obj, 5), squeeze=False)
    rates = {}
    for o, ax in enumerate(axes[0]):
        pts = xy[:, o]
        if region is not None:
            (x0, y0), (x1, y1) = np.asarray(region)
        else:
            (x0, y0), (x1, y1) = pts.min(0) - 0.02, pts.max(0) + 0.02
        ex, ey = np.linspace(x0, x1, bins + 1), np.linspace(y0, y1, bins + 1)
        n_all, _, _ = np.histogram2d(pts[:, 0], pts[:, 1], bins=[ex, ey])
        n_ok, _, _ = np.histogram2d(pts[ok, 0], pts[ok, 1], bins=[ex, ey])
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.where(n_all > 0, n_ok / n_all, np.nan)
        cmap = plt.get_cmap("RdYlGn").with_extremes(bad="lightgrey")
        im = ax.imshow(rate.T, origin="lower", extent=(ex[0], ex[-1], ey[0], ey[-1]), vmin=0, vmax=1, cmap=cmap,
                       aspect="equal")
        ax.scatter(pts[ok, 0], pts[ok, 1], s=18, c="k", label=f"success ({ok.sum()})")
        ax.scatter(pts[~ok, 0], pts[~ok, 1], s=18, facecolors="none", edgecolors="k",
                   label=f"failure ({(~ok).sum()})")
        ax.set_title(f"{names[o]} placement")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize=7, loc="upper right")
        fig.colorbar(im, ax=ax, shrink=0.8, label="success rate")
        rates[names[o]] = rate
    fig.suptitle(title or f"Robot success over object placements ({len(ok)} episodes, "
                          f"{100 * ok.mean():.0f} % success)")
    _save(fig, out)
    return {"episodes": int(len(ok)), "success_rate": float(ok.mean()), "cell_rates": rates}
