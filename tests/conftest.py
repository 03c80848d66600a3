"""Shared fixtures. Real Prefect (one temporary API server per test session), real DuckDB."""


import contextlib
import fcntl
import os
import shutil
import tempfile
from pathlib import Path

# Test workers share the cores: one compute thread per process (BLAS, OpenMP/torch, llama.cpp), not one
# per core in each, whose spinning threads would wait for each other (the user's setting wins).
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "DEMOFORGE_LLM_THREADS"):
        os.environ.setdefault(_name, "1")

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

import demoforge.lib  # noqa: F401,E402  (MUJOCO_GL before mujoco)
from tests.support.paths import TESTS  # noqa: E402

SHARED_DATA = demoforge.lib.SHARED_DATA

# Hypothesis: CI draws the same examples on every run (a red CI run is a real regression, not a new
# random draw, and a rerun reproduces it); local runs keep drawing new examples and remember failing
# ones in .hypothesis/. Chosen by $HYPOTHESIS_PROFILE, else "ci" when $CI is true (CI services set it).
settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("dev", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE")
                      or ("ci" if os.environ.get("CI", "").lower() in ("1", "true", "yes") else "dev"))

# Folder digests (demoforge.tasks.common) of the suite's temporary takes: remembered in the temporary directory,
# not in the user's cache folder; the suite's subprocesses inherit this.
os.environ.setdefault("DEMOFORGE_DIGEST_CACHE", os.path.join(tempfile.gettempdir(), "demoforge-test-digests"))

# A skip is only for what is truly absent, and says what (a test that needs ../shared/data says so:
# CI has it). $DEMOFORGE_FAIL_ON_SKIP=1 (set by .ci/run) makes any skip fail the run, whether or not
# ../shared/data is here: a skip in CI means something the suite needs went missing, or a test hides
# an error behind a skip.
FAIL_ON_SKIP = os.environ.get("DEMOFORGE_FAIL_ON_SKIP", "") not in ("", "0")

# Free space the suite needs in the temporary directory (synthetic takes, warehouses, videos, model
# weights the tests build): measured peak 1-2 GB (docs/development.md), plus a margin. A CI run that
# started on a nearly full disk ended with 71 fixture errors; one clear message up front is better.
MIN_FREE_TMP_BYTES = 3 * 1024**3


def pytest_sessionstart(session):
    tmp = tempfile.gettempdir()
    free = shutil.disk_usage(tmp).free
    if free < MIN_FREE_TMP_BYTES:
        pytest.exit(f"only {free / 1024**3:.1f} GiB free in {tmp}; the test suite needs about "
                    f"{MIN_FREE_TMP_BYTES / 1024**3:.0f} GiB there for its synthetic takes and warehouses. "
                    f"Free some space (old pytest-of-* folders, warehouse/ copies) or point TMPDIR at a "
                    f"larger disk, then run `make test` again.", returncode=3)


def _skipped(session) -> list:
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    return list(reporter.stats.get("skipped", [])) if reporter is not None else []


def pytest_sessionfinish(session, exitstatus):
    if FAIL_ON_SKIP and _skipped(session) and exitstatus in (pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter):
    skipped = terminalreporter.stats.get("skipped", [])
    if FAIL_ON_SKIP and skipped:
        terminalreporter.write_line(
            f"DEMOFORGE_FAIL_ON_SKIP: {len(skipped)} test(s) skipped (reasons in the short test summary; "
            f"{SHARED_DATA} is {'present' if SHARED_DATA.is_dir() else 'absent'}): the run fails", red=True, bold=True)


# Scheduling under `make test` (pytest-xdist, `--dist loadfile`: whole files per worker). xdist alone
# hands out the files with the most tests first, so the one-test flows/test_evaluate.py (the longest file)
# used to start last and run alone for minutes at the end. The suite orders the files itself, longest
# first (measured: docs/results/issue-24-tests.md, again when the tests were mirrored), so the long ones
# overlap and short files fill in at the end; the files that run the embedded LLM (llama.cpp, one thread
# per core) form one unit, so no two of them run at the same time on the 2 cores (each ran 3-7 x slower
# when they did).
# Files are named by their path under tests/ (several folders hold a test_<module>.py of the same name).
LONGEST_FIRST = (
    "flows/test_evaluate.py", "end_to_end/test_bad_inputs.py", "envs/test_robot_env.py", "runtime/test_runners_dask.py",
    "flows/test_closed_loop.py", "lib/task_library/test_task_library.py", "flows/test_ingest_hand_tracking.py",
    "cli/test_cli.py", "flows/test_augment.py", "runtime/test_annotate.py", "flows/test_sim.py",
    "flows/test_deployments.py", "schemas/test_catalog.py", "lib/takes/sources/test_sources.py", "test_packaging.py",
    "flows/test_table3.py",
)
EMBEDDED_LLM = ("lib/llm/test_local_backend.py", "lib/llm/test_grammar.py", "lib/llm/test_number_format.py",
                "lib/llm/test_openai_backend_server.py", "lib/llm/test_structured_decoding.py",
                "lib/llm/test_reduced_vocab.py")
EMBEDDED_LLM_UNIT = "embedded-llm"


def _under_tests(path) -> str:
    """A test file's path under tests/ (as LONGEST_FIRST and EMBEDDED_LLM name it), or its name if elsewhere."""
    path = Path(path).resolve()
    return path.relative_to(TESTS).as_posix() if path.is_relative_to(TESTS) else path.name


def _file_rank(name: str) -> int:
    if name in EMBEDDED_LLM:  # one unit, placed as one long file (after flows/test_evaluate.py)
        return 1
    if name in LONGEST_FIRST:
        return 2 * LONGEST_FIRST.index(name)
    return 2 * len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    """Files in the order above (a stable sort: the tests of a file stay together and in order)."""
    items.sort(key=lambda item: _file_rank(_under_tests(item.path)))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """`--dist loadfile` with the suite's own order (not xdist's most-tests-first) and the embedded-LLM
    files as one work unit."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SuiteScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            scope = super()._split_scope(nodeid)
            return EMBEDDED_LLM_UNIT if _under_tests(config.rootpath / scope) in EMBEDDED_LLM else scope

    config.option.loadscopereorder = False  # the collection's order, set above
    return SuiteScheduling(config, log)


@pytest.fixture(scope="module", autouse=True)
def _embedded_llm_on_one_core(request):
    """Under xdist, the embedded-LLM files run on one core of their own. llama.cpp starts one thread per
    core this process may use (demoforge.lib.llm.local_backend: its CPU affinity) and its threads wait
    for each other at every step; with the other worker busy on the same 2 cores, a thread that is not
    scheduled stalls the rest (test_llm_backends: 29 s alone, 170 s beside other tests). Pinned to one
    core, the model runs one thread (the same greedy answers), the llama.cpp server these files start
    too; the other worker keeps the other core. Module scope: before the files' module fixtures."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if request.module.__file__ is None or _under_tests(request.module.__file__) not in EMBEDDED_LLM \
            or workers < 2 or not hasattr(os, "sched_setaffinity"):
        yield
        return
    cpus = os.sched_getaffinity(0)
    if len(cpus) > 1:
        os.sched_setaffinity(0, {max(cpus)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cpus)


# Under pytest-xdist the controller starts one Prefect server for all workers, while they start up
# and collect; each worker's session then talks to it instead of starting its own (about 9 s of CPU
# each, and about 1.4 s a minute for its background services). Its URL reaches the workers in this
# variable (not PREFECT_API_URL: tests that start demoforge without an API must still get its own
# temporary server).
SHARED_PREFECT_API, SHARED_PREFECT_LOG = "DEMOFORGE_TEST_PREFECT_API_URL", "DEMOFORGE_TEST_PREFECT_LOG"


class _SharedPrefectServer:
    """`prefect server start` on a free loopback port, with its own home and SQLite database in a
    temporary folder; not waited for here (the workers wait for its health check). The API only
    (--no-services): the scheduler, late-run, event-persister, task-run-recorder and automation
    services do nothing a test checks, and halved the server's CPU over a run (54 s -> 27 s)."""

    def __init__(self):
        import socket
        import subprocess
        import sys

        self.folder = Path(tempfile.mkdtemp(prefix="demoforge-test-prefect-"))
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
        self.api_url = f"http://127.0.0.1:{port}/api"
        self.log = self.folder / "server.log"
        env = {**os.environ, "PREFECT_HOME": str(self.folder / "home"), "PREFECT_UI_ENABLED": "false",
               "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
               "PREFECT_SERVER_DATABASE_CONNECTION_URL": f"sqlite+aiosqlite:///{self.folder / 'prefect.db'}"}
        with self.log.open("w") as log:
            self.process = subprocess.Popen(
                [str(Path(sys.executable).parent / "prefect"), "server", "start", "--host", "127.0.0.1", "--port",
                 str(port), "--no-ui", "--analytics-off", "--no-services", "--log-level", "ERROR"],
                env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def stop(self):
        self.process.terminate()
        try:
            self.process.wait(30)
        except Exception:  # noqa: BLE001 (TimeoutExpired, or already gone)
            self.process.kill()
            self.process.wait()
        shutil.rmtree(self.folder, ignore_errors=True)


def pytest_configure(config):
    if os.environ.get("PYTEST_XDIST_WORKER") or not getattr(config.option, "numprocesses", None):
        return  # a worker, or no xdist: the session fixture starts a server when a test needs one
    server = _SharedPrefectServer()
    config._demoforge_prefect_server = server
    # the workers, started after this hook, inherit both
    os.environ.update({SHARED_PREFECT_API: server.api_url, SHARED_PREFECT_LOG: str(server.log)})


def pytest_unconfigure(config):
    server = getattr(config, "_demoforge_prefect_server", None)
    if server is not None:
        server.stop()
        os.environ.pop(SHARED_PREFECT_API, None)
        os.environ.pop(SHARED_PREFECT_LOG, None)


def _wait_until_healthy(api_url: str, timeout_s: float = 180.0) -> None:
    """Return once the shared server answers its health check; fail with its log if it does not come up."""
    import time

    import httpx

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if httpx.get(f"{api_url}/health", timeout=5).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline:
            log = Path(os.environ.get(SHARED_PREFECT_LOG, "/nonexistent"))
            tail = log.read_text()[-2000:] if log.is_file() else "(no log)"
            pytest.fail(f"the shared Prefect server at {api_url} did not answer its health check within "
                        f"{timeout_s:.0f} s; its log ({log}):\n{tail}", pytrace=False)
        time.sleep(0.2)


@pytest.fixture(scope="session")
def prefect_api():
    """A real Prefect API for flows run by tests: the server shared by the xdist workers, or else a
    temporary one for this session (started once, on first use)."""
    from demoforge.runtime.runners import flow_heartbeats_off_unless_set

    shared = os.environ.get(SHARED_PREFECT_API)
    if not shared:
        from prefect.testing.utilities import prefect_test_harness

        with prefect_test_harness(server_startup_timeout=120), flow_heartbeats_off_unless_set():
            yield
        return
    import prefect.context
    from prefect.settings import PREFECT_API_URL, temporary_settings

    _wait_until_healthy(shared)
    # flows called directly by tests run as demoforge's commands run them (runners.run_flow)
    with temporary_settings(updates={PREFECT_API_URL: shared}), flow_heartbeats_off_unless_set():
        # also for threads whose context was copied before this fixture (as prefect_test_harness does)
        with prefect.context._temporary_global_settings_context(prefect.context.get_settings_context()):
            yield
            _drain_prefect_workers()


def _drain_prefect_workers():
    """Send the logs and events still queued in this process while the server is up (as
    prefect_test_harness does before it stops its server)."""
    import inspect

    from prefect.events.worker import EventsWorker
    from prefect.logging.handlers import APILogWorker
    from prefect.utilities.asyncutils import run_coro_as_sync

    async def drain():
        try:
            result = APILogWorker.instance().drain()
            if inspect.isawaitable(result):
                await result
        except RuntimeError:  # never started
            pass
        result = EventsWorker.drain_all()
        if inspect.isawaitable(result):
            await result

    run_coro_as_sync(drain())


@pytest.fixture(scope="session")
def prefect_api_env(prefect_api):
    """Environment for a `demoforge` or `prefect` subprocess: the session's Prefect API, so the
    subprocess does not start a temporary server of its own (13 s each on 2 loaded cores)."""
    from prefect.settings import PREFECT_API_URL

    return {"PREFECT_API_URL": PREFECT_API_URL.value()}


@pytest.fixture()
def warehouse(tmp_path, monkeypatch):
    root = tmp_path / "warehouse"
    root.mkdir()
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(root))
    return root


@pytest.fixture(scope="module")
def episode_wh(tmp_path_factory):
    """An episode database of the scripted pouring demonstration (tests/support/episodes.py), once per test
    module: (warehouse, what was written)."""
    from tests.support.episodes import build_episode_warehouse

    root = tmp_path_factory.mktemp("wh_exports") / "warehouse"
    root.mkdir()
    info = build_episode_warehouse(root)
    return root, info


@contextlib.contextmanager
def _run_wide_folder(tmp_path_factory, name: str):
    """A folder shared by every pytest-xdist worker of this run (in the run's base temporary folder;
    without xdist, in the session's), held under an exclusive file lock: the first worker to get here
    makes what goes in it, the others wait for it and reuse it."""
    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / name
    folder.mkdir(exist_ok=True)
    with open(folder.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield folder
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def trash_take(tmp_path_factory):
    """A full synthetic trash_in_bin take (about 240 frames), rendered once per test run: the xdist
    workers share it (read only, as every test uses it), so it is rendered, and its 300 MB hashed
    (the folder digests remembered on disk, keyed by path), once instead of once per worker."""
    from demoforge.lib.synth.take import generate_take

    with _run_wide_folder(tmp_path_factory, "shared_takes") as folder:
        out, done = folder / "synth_trash_in_bin_s0000", folder / "synth_trash_in_bin_s0000.done"
        if not done.is_file():
            shutil.rmtree(out, ignore_errors=True)  # a render cut short
            generate_take("trash_in_bin", 0, False, out, video=False)
            done.touch()
    return out


@pytest.fixture(scope="session")
def _ingested_trash(tmp_path_factory, trash_take, prefect_api):
    """trash_take ingested once (default options) into a warehouse at a fixed path, and a pristine copy."""
    from demoforge.flows.ingest import ingest_take

    root = tmp_path_factory.mktemp("ingested")
    live = root / "warehouse"
    ingest_take(str(trash_take), str(live), show_progress=False)
    shutil.copytree(live, root / "pristine")
    return live, root / "pristine"


@pytest.fixture()
def ingested_warehouse(_ingested_trash, monkeypatch):
    """A warehouse holding trash_take's ingest and its cache: a flow that builds on the ingest (augment,
    simulate, llm-eval) finds every ingest stage cached instead of ingesting the take again (4-5 s each).
    Cache keys name the warehouse folder, so the warehouse is always at the same path, restored from the
    pristine copy for each test (tests run one at a time)."""
    live, pristine = _ingested_trash
    shutil.rmtree(live)
    shutil.copytree(pristine, live)
    monkeypatch.setenv("DEMOFORGE_WAREHOUSE", str(live))
    return live


@pytest.fixture(scope="session")
def llama_server(tmp_path_factory):
    """llama-cpp-python's OpenAI-compatible server (`python -m llama_cpp.server`) serving the embedded
    Gemma 3 270M GGUF on a free loopback port, once per session: (base URL, model id). The files that
    use it run in the embedded-LLM unit (EMBEDDED_LLM), on that unit's core."""
    import json
    import socket
    import subprocess
    import sys
    import time
    import urllib.request

    from demoforge.lib.llm.llama_models import cpu_threads, ensure_gguf

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    log = tmp_path_factory.mktemp("llama_server") / "server.log"
    threads = str(cpu_threads())
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "llama_cpp.server", "--model", str(ensure_gguf()), "--host", "127.0.0.1",
             "--port", str(port), "--n_ctx", "4096", "--n_threads", threads, "--n_threads_batch", threads],
            stdout=out, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}/v1"
    try:
        deadline = time.monotonic() + 90
        while True:  # ready when /v1/models answers
            if proc.poll() is not None:
                pytest.fail(f"llama_cpp.server exited with {proc.returncode}: {log.read_text()[-2000:]}")
            try:
                with urllib.request.urlopen(base + "/models", timeout=2) as r:
                    model_id = json.loads(r.read())["data"][0]["id"]
                break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail(f"llama_cpp.server did not answer on {base} within 90 s")
                time.sleep(0.2)
        yield base, model_id
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
