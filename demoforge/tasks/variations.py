"""Prefect task of the Table 4 analogue: seeded varied scenes (demoforge.lib.sim.variations) -> a trajectory per strategy ->
the robot in MuJoCo on the varied scene (demoforge.lib.sim.variation_scene), one call per (task, take)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import pyarrow as pa

import demoforge.schemas.variations  # noqa: F401  (registers variation_trials)
from demoforge.lib.sim.variation_scene import VariationScene
from demoforge.lib.sim.variations import make_variation
from demoforge.lib.task_library import get_task
from demoforge.lib.trajectories.augmentation import estimate_object_poses, from_scripted_demo, transform_demo
from demoforge.lib.trajectories.retrieval import KeypointIndex
from demoforge.schemas.catalog import query
from demoforge.schemas.core import table_files, write_table
from demoforge.schemas.reads.demonstration import load_demo_source
from demoforge.schemas.reads.episodes import episode_actions
from demoforge.tasks.common import Manifest, stage_task

VARIATION_TRIALS_VERSION = "1"
VARIATION_STRATEGIES = ("replay_top1", "transform_demo", "transform_scripted")


def database_files(warehouse: str, task: str, take: str) -> list[Path]:
    """The episode database's files (their content keys the stage's cache)."""
    return table_files("episodes", warehouse, task=task, take=take)


def code_files() -> list[Path]:
    """Sources whose changes change the outcomes (scenes, variations, the simulator, the transforms):
    their content keys the stage's cache, so a physics change in lib/sim re-runs the trials."""
    root = Path(__file__).resolve().parents[1] / "lib"
    return sorted([*(root / "sim").rglob("*.py"), *(root / "task_library").glob("*.py"),
                   *(root / "trajectories" / "augmentation").glob("*.py"), root / "trajectories" / "retrieval.py",
                   *(root / "geometry").glob("*.py")])


class _Strategies:
    """Trajectory producers for one (task, take), loading each input once."""

    def __init__(self, warehouse: str, task: str, take: str, strategies: Sequence[str]):
        self.warehouse, self.task, self.take = warehouse, task, take
        self.base = get_task(task)
        self.index = self.source = self.scripted = None
        if "replay_top1" in strategies:
            ep = query("SELECT episode_id, object_keypoints FROM episodes "
                       "WHERE task = ? AND take = ? AND valid ORDER BY episode_id", warehouse, [task, take])
            if ep.num_rows == 0:
                raise ValueError(f"no valid episodes of {task}/{take}: run `demoforge augment` on the take first")
            self.index = KeypointIndex(np.asarray(ep.column("object_keypoints").to_pylist(), float),
                                       ids=np.asarray(ep.column("episode_id").to_numpy()))
        if "transform_demo" in strategies:
            self.source = load_demo_source(take, task, warehouse)
        if "transform_scripted" in strategies:
            self.scripted = _scripted_source(warehouse, task, take)

    def actions(self, strategy: str, keypoints: np.ndarray) -> tuple[np.ndarray, int, float | None]:
        """(actions (n, 2, 8), replayed episode id or -1, retrieval MSE or None) for a scene seen through
        its object keypoints (what a deployed system observes)."""
        if strategy == "replay_top1":
            hit = self.index.query(keypoints, k=1)
            eid = int(hit.ids[0, 0])
            return episode_actions(self.warehouse, self.task, self.take, [eid])[eid], eid, float(hit.mse[0, 0])
        src = self.source if strategy == "transform_demo" else self.scripted
        poses = estimate_object_poses(keypoints, self.base.keypoints_local, self.base.keypoint_object)
        return transform_demo(src, poses), -1, None


def _scripted_source(warehouse: str, task: str, take: str):
    """The take's scripted ground-truth demonstration (synthetic takes only) as a DemoSource."""
    rows = query("SELECT source, seed, mirror FROM takes WHERE take = ? AND task = ?",
                 warehouse, [take, task]).to_pylist()
    if not rows or rows[0]["source"] != "synthetic" or rows[0]["seed"] < 0:
        raise ValueError(f"strategy transform_scripted needs a synthetic take registered in `takes`; {task}/{take} "
                         "is not one (use replay_top1 / transform_demo for recorded takes)")
    spec = get_task(task)
    return from_scripted_demo(spec, spec.scripted_demo(int(rows[0]["seed"]), mirror=bool(rows[0]["mirror"])))


@stage_task(name="variation_trials", version=VARIATION_TRIALS_VERSION)
def variation_trials(task: str, take: str, warehouse: str, database: list[Path], kinds: Sequence[str],
                     strategies: Sequence[str], trials: int = 2, seed: int = 0,
                     code: list[Path] | None = None, library_version: str = "",
                     variations_version: str = "") -> Manifest:
    """`trials` seeded scenes per variation kind; each strategy's trajectory executed on the varied scene.
    `database` (the episode table's files), `code` (code_files()), `library_version` and
    `variations_version` key the cache; they are not used otherwise."""
    producers = _Strategies(warehouse, task, take, strategies)
    rows = []
    for kind in kinds:
        for trial in range(trials):
            v = make_variation(task, kind, seed, trial)
            scene = VariationScene(v)
            kp = scene.keypoints
            for strategy in strategies:
                t0 = time.perf_counter()
                row = {"task": task, "take": take, "variation": kind, "variation_params": json.dumps(v.params),
                       "variation_summary": v.summary(), "trial": trial, "seed": seed, "strategy": strategy,
                       "query_keypoints": kp.tolist(), "retrieved_episode_id": -1, "retrieval_mse": None,
                       "n_distractors": len(v.distractors), "distractor_max_shift_m": 0.0, "sim_wall_s": 0.0}
                try:
                    actions, eid, mse = producers.actions(strategy, kp)
                    row.update(retrieved_episode_id=eid, retrieval_mse=mse)
                    r = scene.execute(actions)
                except Exception as e:  # noqa: BLE001 - one broken trial is a failed row, never a lost table
                    row.update(success=False, failure_reason="error", detail=f"{type(e).__name__}: {e}"[:500])
                else:
                    row.update(success=bool(r.success), failure_reason="" if r.success else str(r.failure),
                               detail=str(r.detail), sim_wall_s=float(r.wall_s),
                               distractor_max_shift_m=float(scene.last_distractor_shift.max(initial=0.0)))
                row["wall_s"] = time.perf_counter() - t0
                rows.append(row)
    written = write_table("variation_trials", pa.Table.from_pylist(rows), warehouse)
    return Manifest.from_written("variation_trials", written)
