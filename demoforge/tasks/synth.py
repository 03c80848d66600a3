"""Prefect tasks of the synthetic-demonstration stage: thin adapters around demoforge.lib.synth and demoforge.lib.task_library."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import pyarrow as pa

from demoforge.lib.sim.replay import replay
from demoforge.lib.task_library import get_task
from demoforge.schemas.core import read_table_file, write_table
from demoforge.schemas.synthetic import GT_TABLES
from demoforge.tasks.common import Manifest, stage_task




def _replace_dir(tmp: Path, final: Path) -> None:
    """Move a completed folder into place; a half-written take is never visible under its name."""
    trash = final.with_name(f".{final.name}.old")
    if trash.exists():
        shutil.rmtree(trash)
    if final.exists():
        final.rename(trash)
    tmp.rename(final)
    if trash.exists():
        shutil.rmtree(trash)


from demoforge.lib.synth.take import GENERATOR_VERSION  # noqa: E402
from demoforge.lib.task_library import TASK_LIBRARY_VERSION  # noqa: E402


@stage_task(name="synthesize_take", version=f"1/gen{GENERATOR_VERSION}/tasks{TASK_LIBRARY_VERSION}")
def synthesize_take(task: str, seed: int, mirror: bool, takes_dir: str, warehouse: str,
                    depth_noise: bool = True, video: bool = True, max_frames: int | None = None,
                    show_progress: bool = True, hand_style: str = "capsule") -> Manifest:
    """Script, render and write one synthetic take, replay it in physics, register it in `takes`."""
    # imported when called: tests replace what it names
    from demoforge.lib.synth.take import GENERATOR, GENERATOR_VERSION, PROVENANCE, generate_take, take_id

    name = take_id(task, seed, mirror)
    final = Path(takes_dir) / name
    tmp = Path(takes_dir) / f".{name}.partial"
    if tmp.exists():
        shutil.rmtree(tmp)  # left by a crash: start this take over
    bar = None
    if show_progress:
        from tqdm.auto import tqdm

        bar = tqdm(desc=name, unit="frame", leave=False)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.update(done - bar.n)

    t0 = time.perf_counter()
    summary = generate_take(task, seed, mirror, tmp, depth_noise=depth_noise, video=video,
                            progress=progress, max_frames=max_frames, hand_style=hand_style)
    generate_seconds = time.perf_counter() - t0
    if bar is not None:
        bar.close()
    _replace_dir(tmp, final)

    replay_success = replay_reason = replay_seconds = None
    if max_frames is None:  # a truncated take cannot complete its task
        t0 = time.perf_counter()
        result = replay(get_task(task).scripted_demo(seed, mirror=mirror))
        replay_seconds = time.perf_counter() - t0
        replay_success, replay_reason = bool(result.success), str(result.reason)

    written = []
    for gt in GT_TABLES:
        written += write_table(gt, read_table_file(gt, final / "ground_truth" / f"{gt}.parquet"), warehouse)
    row = {
        "take": name, "task": task, "source": "synthetic", "mirror": bool(mirror), "seed": int(seed),
        "n_frames": summary.n_frames, "fps": float(summary.fps),
        "duration_s": summary.n_frames / float(summary.fps), "path": str(final.resolve()),
        "generator": f"{GENERATOR} {GENERATOR_VERSION}", "provenance": PROVENANCE,
        "visible_left": summary.visible_fraction[0], "visible_right": summary.visible_fraction[1],
        "replay_success": replay_success, "replay_reason": replay_reason,
        "generate_seconds": generate_seconds, "replay_seconds": replay_seconds,
    }
    written += write_table("takes", pa.Table.from_pylist([row]), warehouse)
    return Manifest.from_written("takes", written, final)
