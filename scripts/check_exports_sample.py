"""A small real warehouse for `make check-exports`: the pouring task's scripted demonstration,
augmented into translated and mirrored episodes, with a registered take folder whose camera.json is
the synthetic head camera (so `--with-images` has a camera to render from).

    .venv/bin/python scripts/check_exports_sample.py WAREHOUSE TAKES_DIR [--episodes N]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TASK, TAKE = "pouring", "synth_pouring_s0000"
DEMO_SEED = 1  # the scripted demonstration the ALOHA arms reach at every step (seed 0's they do not)


def build(warehouse: Path, takes_dir: Path, n: int = 12, n_mirrored: int = 6, seed: int = 1) -> dict:
    from demoforge.lib.trajectories.augmentation import DemoSource, generate_episodes
    from demoforge.lib.synth.render import HEIGHT, WIDTH, camera_K, camera_T_world_camera
    from demoforge.lib.task_library import get_task
    from demoforge.schemas.core import write_table
    from demoforge.tasks.augment import episode_steps_columns, episodes_columns

    spec = get_task(TASK)
    demo = spec.scripted_demo(DEMO_SEED)
    src = DemoSource(task=TASK, trajectory=demo.gripper_actions(), keypoints=demo.keypoints()[0],
                     keypoint_object=spec.keypoint_object, keypoints_local=spec.keypoints_local,
                     segments=demo.segments, object_arm=spec.object_arm(False))
    batch = generate_episodes(src, n=n, n_mirrored=n_mirrored, seed=seed, workspace=spec.workspace, workers=1)
    write_table("episodes", episodes_columns(TASK, TAKE, seed, batch), warehouse)
    write_table("episode_steps", episode_steps_columns(TASK, TAKE, batch), warehouse)
    take = takes_dir / TAKE
    take.mkdir(parents=True, exist_ok=True)
    (take / "camera.json").write_text(json.dumps({
        "K": camera_K().tolist(), "width": WIDTH, "height": HEIGHT,
        "T_world_camera": camera_T_world_camera().tolist(), "fps": 30.0, "depth_unit": "m"}))
    write_table("takes", takes_row(take, int(batch.lengths[0])), warehouse)
    return {"episodes": len(batch), "valid": int(batch.valid.sum())}


def takes_row(take: Path, n_frames: int = 0) -> dict:
    """The `takes` row registering a take folder (so the export finds its camera.json)."""
    return {
        "take": [take.name], "task": [TASK], "source": ["synthetic"], "mirror": [False], "seed": [0],
        "n_frames": np.array([n_frames], np.int32), "fps": [30.0], "duration_s": [n_frames / 30.0],
        "path": [str(take.resolve())], "generator": ["check_exports_sample"],
        "provenance": ["scripted demonstration (task library)"], "visible_left": [None], "visible_right": [None],
        "replay_success": [None], "replay_reason": [None], "generate_seconds": [0.0], "replay_seconds": [None],
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("warehouse", type=Path)
    ap.add_argument("takes_dir", type=Path)
    ap.add_argument("--episodes", type=int, default=12)
    a = ap.parse_args()
    a.warehouse.mkdir(parents=True, exist_ok=True)
    print(json.dumps(build(a.warehouse, a.takes_dir, n=a.episodes, n_mirrored=a.episodes // 2)))
