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
import signal
import subprocess
import sys
import threading
from typing import Any

from demoforge.lib.errors import release_frames
from demoforge.lib.settings import read_settings

ENV_RUNNER = "DEMOFORGE_TASK_RUNNER"
ENV_ADDRESS = "DEMOFORGE_DASK_ADDRESS"
ENV_WORKERS = "DEMOFORGE_DASK_WORKERS"
RUNNERS = ("threads", "dask")


def runner_kind() -> str:
    kind = read_settings().task_runner
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
    raw = read_settings().dask_workers
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

        _share_prefect_api()
        _LOCAL_CLUSTER = LocalCluster(**local_cluster_kwargs(dask_workers()))
        atexit.register(_close_local_cluster)
    return _LOCAL_CLUSTER.scheduler_address


def _share_prefect_api() -> None:
    """Without PREFECT_API_URL every process uses its own temporary Prefect server; Dask workers would
    each start one (20 s apiece) and their task runs would not be the flow's. Start this process's
    temporary server now and publish its URL, so the workers spawned next report to the same API."""
    if os.environ.get("PREFECT_API_URL"):
        return
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()  # the same singleton the flow's own client would start
    server.start()
    os.environ["PREFECT_API_URL"] = server.api_url


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
    return DaskTaskRunner(address=read_settings().dask_address or _local_cluster_address())


def with_runner(flow_obj):
    """`flow_obj` with the configured task runner (itself when the default is configured)."""
    runner = make_task_runner()
    return flow_obj if runner is None else flow_obj.with_options(task_runner=runner)


def run_flow(flow_obj, *args: Any, **kwargs: Any) -> Any:
    """Call a flow with the configured task runner; stop here if Ctrl-C was pressed."""
    check_interrupted()
    guard_temporary_api_server()
    try:
        with flow_heartbeats_off_unless_set():
            result = with_runner(flow_obj)(*args, **kwargs)
    except Exception as e:
        release_frames(e)  # Prefect's run state keeps the error to the end of the process
        raise
    check_interrupted()
    return result


HEARTBEAT_VARIABLES = ("PREFECT_FLOWS_HEARTBEAT_FREQUENCY", "PREFECT_RUNNER_HEARTBEAT_FREQUENCY")


@contextlib.contextmanager
def flow_heartbeats_off_unless_set():
    """No flow-run heartbeats, unless the user set their frequency in the environment.

    Prefect 3.8 starts a heartbeat thread for every flow run and subflow run (by default every 180 s)
    and joins it when the run ends; the thread sleeps in 1-second steps, so every run ended up to a
    second late (10 empty flows: 10.7 s with heartbeats, 0.8 s without). The main job runs a dozen
    subflows, ingest-folder one per take. Heartbeats only feed a crashed-run automation, which
    demoforge does not set up; flows served by `demoforge serve` run in processes of Prefect's own
    and keep them."""
    if any(os.environ.get(name) for name in HEARTBEAT_VARIABLES):
        yield
        return
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        yield


_INTERRUPTED = threading.Event()


def install_interrupt_handler() -> None:
    """Ctrl-C stops a command at once, or at the latest when the current flow returns.

    Python raises KeyboardInterrupt wherever the main thread is; if that lands in a part of Prefect
    that records the interruption and carries on, the run would simply continue. The flag set here
    is checked around every flow call, so the command stops at the next stage boundary regardless.
    A second Ctrl-C exits immediately (every table write is atomic, so nothing half-written remains).
    Left alone when SIGINT is ignored (a command started in the background)."""
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return

    def on_sigint(signum, frame):
        if _INTERRUPTED.is_set():
            os._exit(130)
        _INTERRUPTED.set()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)


def check_interrupted() -> None:
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt("interrupted by Ctrl-C: run the command again to resume")


def _die_with_parent() -> None:  # runs in the child between fork and exec
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def temporary_server_log() -> "Path":
    """Where the temporary API server's own output goes: ``$PREFECT_HOME/demoforge-temporary-server.log``."""
    from pathlib import Path

    from prefect.settings import get_current_settings

    return Path(get_current_settings().home) / "demoforge-temporary-server.log"


def guard_temporary_api_server() -> None:
    """Make Prefect's temporary API server (used when PREFECT_API_URL is unset) survive Ctrl-C, die
    with its parent, and write its own log to a file instead of the terminal.

    Prefect starts it as a plain child process, so Ctrl-C in a terminal (SIGINT to the whole
    foreground process group) kills it at the same moment as the flow, which then spends minutes
    retrying to record the interruption against a dead server instead of exiting. Here it runs in a
    session of its own (no terminal signals) and receives SIGTERM when its parent dies (even by
    SIGKILL), so no orphan server is left behind either. Its background services log their errors
    with tracebacks (the task-run recorder cancelled while it flushes at shutdown, SQLite "database is
    locked" when several commands share ~/.prefect/prefect.db); those are the server's business, not
    the command's: they go to :func:`temporary_server_log` (appended). The command line is Prefect
    3.8.8's own.
    """
    if os.environ.get("PREFECT_API_URL") or not sys.platform.startswith("linux"):
        return
    from prefect.settings import get_current_settings

    if get_current_settings().api.url:  # a real server (or a test harness) is configured
        return
    from prefect.server.api import server as api_server

    cls = api_server.SubprocessASGIServer
    if getattr(cls, "_demoforge_guarded", False):
        return

    def _run_uvicorn_command(self):
        import prefect
        from prefect.settings import get_current_settings

        server_env = {"PREFECT_UI_ENABLED": "0", "PREFECT__SERVER_EPHEMERAL": "1", "PREFECT__SERVER_FINAL": "1"}
        log_path = temporary_server_log()
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(log_path, "ab") as log:  # the child keeps its own descriptor
            return subprocess.Popen(
                args=[sys.executable, "-m", "uvicorn", "--app-dir", str(prefect.__module_path__.parent), "--factory",
                      "prefect.server.api.server:create_app", "--host", "127.0.0.1", "--port", str(self.port),
                      "--log-level", "error", "--lifespan", "on"],
                env={**os.environ, **server_env, **get_current_settings().to_environment_variables(exclude_unset=True)},
                start_new_session=True,
                preexec_fn=_die_with_parent,
                stdout=log, stderr=subprocess.STDOUT,
            )

    cls._run_uvicorn_command = _run_uvicorn_command
    cls._demoforge_guarded = True
    # start it now, from this (the main) thread: the parent-death signal follows the thread that
    # started the child, and Prefect might otherwise start it from a short-lived helper thread
    cls().start()
