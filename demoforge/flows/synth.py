"""Flow: generate synthetic RGB-D demonstrations with exact ground truth (the embedded default data)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from prefect import flow, get_run_logger

from demoforge.lib.synth import mirror_flags
from demoforge.lib.task_library import TASK_NAMES
from demoforge.tasks.common import Manifest, run_stage
from demoforge.tasks.synth import synthesize_take


def default_takes_dir(warehouse: str | Path) -> Path:
    return Path(warehouse) / "synthetic"


@flow(name="synthesize-takes")
def synthesize_takes(
    warehouse: str,
    tasks: Sequence[str] = ("pouring",),
    takes: int = 1,
    seed: int = 0,
    mirror: str = "no",
    takes_dir: str | None = None,
    depth_noise: bool = True,
    video: bool = True,
    max_frames: int | None = None,
    show_progress: bool = True,
    hand_style: str = "capsule",
) -> list[Manifest]:
    """Render `takes` takes per task (seeds seed, seed+1, ...) into `takes_dir` and register them.

    mirror: "no" (original hands' roles), "yes" (mirrored variant only) or "both".
    hand_style: "capsule" (default) or "skin" (palm, forearm, sleeve, nails); same ground truth.
    Takes already generated with the same parameters and code version come from the cache.
    """
    logger = get_run_logger()
    unknown = [t for t in tasks if t not in TASK_NAMES]
    if unknown:
        raise ValueError(f"unknown task(s) {unknown}; choose from {', '.join(TASK_NAMES)}")
    if takes < 1:
        raise ValueError("takes must be at least 1")
    flags = mirror_flags(mirror)
    out = Path(takes_dir) if takes_dir else default_takes_dir(warehouse)
    out.mkdir(parents=True, exist_ok=True)
    manifests = []
    for task in tasks:
        for k in range(takes):
            for m in flags:
                manifest = run_stage(
                    synthesize_take, warehouse, task=task, seed=seed + k, mirror=m,
                    takes_dir=str(out.resolve()), warehouse=str(warehouse), depth_noise=depth_noise,
                    video=video, max_frames=max_frames, show_progress=show_progress, hand_style=hand_style,
                )
                logger.info("take %s: %d rows", manifest.path, manifest.rows)
                manifests.append(manifest)
    return manifests
