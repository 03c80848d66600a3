"""Scale-out: the augmentation and simulation flows on a 2-worker Dask cluster (prefect-dask) write the
same tables as the default thread-pool runner, and their tasks really ran on the cluster."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pytest
from tests.support.tables import canonical_table

VENV_BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow

TABLES = ("gripper_poses", "object_keypoints", "segments", "episodes", "episode_steps", "sim_results")
VOLATILE = {"wall_s"}  # wall-clock time of a simulated episode


def _run_pipeline(take: Path, warehouse: Path, env: dict) -> None:
    env = {**env, "DEMOFORGE_WAREHOUSE": str(warehouse), "MUJOCO_GL": "egl"}
    for args in (["augment", str(take), "-n", "60", "--mirrored", "30"],
                 ["simulate", "--task", "trash_in_bin", "--episodes", "4", "--chunk-size", "2", "--workers", "1"]):
        r = subprocess.run([str(VENV_BIN / "demoforge"), *args], env=env, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, f"demoforge {' '.join(args)} failed:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"


def _same_rows(a: pa.Table, b: pa.Table) -> bool:
    """Equal schemas and values, NaN equal to NaN (missing uv of keypoints out of view)."""
    return a.schema == b.schema and json.dumps(a.to_pylist(), default=str) == json.dumps(b.to_pylist(), default=str)


def _table(warehouse: Path, name: str) -> pa.Table:
    return canonical_table(warehouse, name, VOLATILE)


def test_augment_and_simulate_on_a_two_worker_dask_cluster_equal_the_default_runner(trash_take, tmp_path,
                                                                                   prefect_api_env,
                                                                                   ingested_warehouse):
    from distributed import Client, LocalCluster

    for name in ("distributed", "distributed.nanny", "distributed.scheduler", "distributed.worker"):
        logging.getLogger(name).setLevel(logging.WARNING)
    base = {k: v for k, v in os.environ.items() if not k.startswith("DEMOFORGE_")}
    # every command talks to the session's Prefect API instead of starting a temporary server
    base.update(prefect_api_env, PREFECT_HOME=str(tmp_path / "prefect_home"))

    # the default runner, from the session's ingest of the take (its stages come from the cache)
    threads = ingested_warehouse
    _run_pipeline(trash_take, threads, {**base, "DEMOFORGE_TASK_RUNNER": "threads"})

    # An existing cluster, as on a real deployment: a scheduler address plus a shared Prefect API.
    os.environ["PREFECT_API_URL"] = prefect_api_env["PREFECT_API_URL"]  # the workers spawned below inherit it
    try:
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            _run_pipeline(trash_take, tmp_path / "dask", {**base, "DEMOFORGE_TASK_RUNNER": "dask",
                                                          "DEMOFORGE_DASK_ADDRESS": cluster.scheduler_address})
            with Client(cluster.scheduler_address) as client:
                ran = client.run_on_scheduler(lambda dask_scheduler: sorted(dask_scheduler.task_prefixes))
                workers = len(client.scheduler_info()["workers"])
    finally:
        os.environ.pop("PREFECT_API_URL", None)

    assert workers == 2
    # every stage of the two flows was executed by the cluster, not in the flow's process
    for stage in ("detect_hands", "map_grippers", "segment_take", "augment_take", "simulate_chunk"):
        assert stage in ran, f"{stage} did not run on the Dask cluster (ran: {ran})"
    for name in TABLES:
        a, b = _table(threads, name), _table(tmp_path / "dask", name)
        assert a.num_rows > 0, name
        assert _same_rows(a, b), f"{name}: the Dask run wrote different rows than the default runner"
