"""Which Prefect task runner the flows use: the default thread pool, or Dask (prefect-dask).

Selected by configuration, read when a flow is called (not when it is imported):

    DEMOFORGE_TASK_RUNNER=threads   (default) tasks run in the flow's process
    DEMOFORGE_TASK_RUNNER=dask      tasks run on a Dask cluster:
        DEMOFORGE_DASK_ADDRESS=tcp://host:8786   an existing scheduler, or, when unset,
        DEMOFORGE_DASK_WORKERS=2                 a local cluster of that many worker processes
                                                 (one thread each; started once per command and
                                                 shared by every flow of that command)

What the machines of a cluster must share: the warehouse folder at the same absolute path (tables
and the Prefect result storage `warehouse/_prefect/results` live there; tasks write to it and the
flow reads their manifests), the take folders at the same paths, the same demoforge checkout and
pinned environment, and the Prefect API (`PREFECT_API_URL` of a running server) when the workers
are not started by the command itself.
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Any

ENV_RUNNER = "DEMOFORGE_TASK_RUNNER"
ENV_ADDRESS = "DEMOFORGE_DASK_ADDRESS"
ENV_WORKERS = "DEMOFORGE_DASK_WORKERS"
RUNNERS = ("threads", "dask")


def runner_kind() -> str:
    kind = os.environ.get(ENV_RUNNER, "threads").strip().lower() or "threads"
    if kind not in RUNNERS:
        raise ValueError(f"{ENV_RUNNER}={kind!r} is not a task runner; use one of: {', '.join(RUNNERS)}")
    return kind


def _quiet_dask() -> None:
    # distributed logs every worker start/stop at INFO; demoforge's own progress is what users read.
    for name in ("distributed", "distributed.worker", "distributed.scheduler", "distributed.nanny",
                 "distributed.core", "distributed.http.proxy"):
        logging.getLogger(name).setLevel(logging.WARNING)


def local_cluster_kwargs(workers: int) -> dict[str, Any]:
    return {"n_workers": workers, "threads_per_worker": 1, "processes": True, "dashboard_address": None}


def dask_workers() -> int:
    raw = os.environ.get(ENV_WORKERS, "2")
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"{ENV_WORKERS}={raw!r} must be a whole number of worker processes") from None
    if n < 1:
        raise ValueError(f"{ENV_WORKERS} must be at least 1, got {n}")
    return n


_LOCAL_CLUSTER = None


def _local_cluster_address() -> str:
    """Start this process's local Dask cluster on first use (closed at exit) and return its address,
    so every (sub)flow of one command shares the same workers instead of starting a cluster each."""
    global _LOCAL_CLUSTER
    if _LOCAL_CLUSTER is None:
        import atexit

        from distributed import LocalCluster

        _quiet_dask()
        _LOCAL_CLUSTER = LocalCluster(**local_cluster_kwargs(dask_workers()))
        atexit.register(_close_local_cluster)
    return _LOCAL_CLUSTER.scheduler_address


def _close_local_cluster() -> None:
    global _LOCAL_CLUSTER
    if _LOCAL_CLUSTER is not None:
        with contextlib.suppress(Exception):
            _LOCAL_CLUSTER.close()
        _LOCAL_CLUSTER = None


def make_task_runner():
    """The configured task runner, or None for Prefect's default (a thread pool in this process)."""
    if runner_kind() == "threads":
        return None
    from prefect_dask import DaskTaskRunner

    _quiet_dask()
    return DaskTaskRunner(address=os.environ.get(ENV_ADDRESS) or _local_cluster_address())


def with_runner(flow_obj):
    """`flow_obj` with the configured task runner (itself when the default is configured)."""
    runner = make_task_runner()
    return flow_obj if runner is None else flow_obj.with_options(task_runner=runner)


def run_flow(flow_obj, *args: Any, **kwargs: Any) -> Any:
    """Call a flow with the configured task runner."""
    return with_runner(flow_obj)(*args, **kwargs)


def is_distributed() -> bool:
    """True inside a flow whose task runner is Dask (its tasks must be submitted to run there)."""
    from tasks.common import in_distributed_flow

    return in_distributed_flow()
