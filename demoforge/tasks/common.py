"""Prefect conventions every demoforge task follows.

- Cache keys come from the *content* of a task's inputs plus an explicit code-version salt
  (``stage_task(name=..., version=...)``): never from pickled arrays or the run id. Inputs that are
  files or folders must be passed as :class:`pathlib.Path`; their bytes are hashed. A plain ``str``
  is a literal. A :class:`Manifest` is keyed by its content hash. The warehouse a task writes to
  is an output location, not an input: pass it as ``str`` (as a ``Path`` its changing contents
  would change every key).
- Results (the small manifests) and cache records live under the warehouse, in ``_prefect/``, so a
  warehouse carries its own cache and two warehouses never share one.
- Tasks return a :class:`Manifest` (table, path, rows, content hash), never a large array.
- :func:`run_stage` re-runs a cached task when the file its cached manifest names is gone or
  changed, so deleting a table file and re-running recomputes exactly that stage.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass, is_dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterable

from prefect import task
from prefect.cache_policies import CachePolicy
from prefect.context import TaskRunContext

from demoforge.lib.errors import Reporting, is_user_error, one_line
from demoforge.lib.takes import open_take
from demoforge.lib.takes.sources import cache_key_inputs
from demoforge.schemas.core import WrittenFile, file_sha256

PREFECT_DIR = "_prefect"
# Part of every cache key: results cached before the `demoforge` package pickled other module
# paths (tasks.common.Manifest, ...) and must not be read back.
LAYOUT = "/pkg-demoforge"


@dataclass(frozen=True)
class Manifest:
    """What a task hands to the next one: where its table rows are, how many, and their hash."""

    table: str
    path: str
    rows: int
    content_hash: str
    files: tuple[str, ...] = ()

    @classmethod
    def from_written(cls, table: str, written: Iterable[WrittenFile],
                     path: str | os.PathLike | None = None) -> "Manifest":
        """The manifest of files a task wrote; ``path`` defaults to the first of them."""
        written = sorted(written, key=lambda w: w.path)
        if path is None:
            path = written[0].path if written else table
        h = hashlib.sha256()
        for w in written:
            h.update(w.content_hash.encode())
        return cls(
            table=table,
            path=str(path),
            rows=sum(w.rows for w in written),
            content_hash=h.hexdigest(),
            files=tuple(w.path for w in written),
        )

    def is_intact(self) -> bool:
        """True if every file this manifest names still exists with the recorded content."""
        if not self.files:
            return Path(self.path).exists()
        h = hashlib.sha256()
        for f in sorted(self.files):
            if not Path(f).is_file():
                return False
            h.update(file_sha256(f).encode())
        return h.hexdigest() == self.content_hash


# --- content hashing of inputs -------------------------------------------------------------------

_FILE_HASH_MEMO: dict[tuple, str] = {}
# A file changed less than this long ago is not remembered by its identity: the file system's clock
# ticks coarser than its nanosecond times, so a write in the same tick would keep the identity
# (git's "racily clean" files).
RACY_NS = 2_000_000_000


def _file_digest(path: Path, remember: bool = False) -> str:
    """sha256 of a file, once per process; with ``remember`` also across processes (the digest is kept
    under digest_cache_dir() with the file's identity, as for folders): a multi-GB recording given as a
    take is hashed once, not by every command that ingests, annotates or augments it."""
    st = path.stat()
    key = (str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    digest = _FILE_HASH_MEMO.get(key)
    if digest is not None:
        return digest
    record = None
    if remember:
        record = digest_cache_dir() / "files" / (hashlib.sha256(key[0].encode()).hexdigest()[:32] + ".json")
        try:
            known = json.loads(record.read_text())
            if known.get("identity") == list(key[1:]):
                digest = str(known["sha256"])
        except (OSError, ValueError, KeyError, AttributeError):
            pass
    if digest is None:
        digest = file_sha256(path)
        if time.time_ns() - st.st_mtime_ns < RACY_NS:
            return digest  # still being written, perhaps: a later write could keep these times, so hash it again next time
        if record is not None:
            _write_record(record, {"identity": list(key[1:]), "sha256": digest})
    _FILE_HASH_MEMO[key] = digest
    return digest


def forget_file_digests() -> None:
    """Drop the digests this process remembers (as a new process starts): the on-disk records stay."""
    _FILE_HASH_MEMO.clear()


def _write_record(record: Path, obj: Any) -> None:
    try:  # atomic; a failure only costs hashing again next time
        record.parent.mkdir(parents=True, exist_ok=True)
        tmp = record.with_name(f"{record.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(obj))
        os.replace(tmp, record)
    except OSError:
        pass


from demoforge.lib.settings import digest_cache_dir  # noqa: E402  (re-exported: where digests are remembered)


def _dir_file_digests(folder: Path) -> list[tuple[str, str]]:
    """(relative path, sha256) of every file under ``folder``, sorted. A take is hundreds of MB: every
    command (and every Dask worker) used to hash it again. Each file's digest is remembered on disk
    with its identity (inode, size, mtime and ctime in ns: a write changes ctime, which no tool can
    set back), so an unchanged take is only stat'ed; a changed file is hashed again."""
    folder = folder.resolve()
    record = digest_cache_dir() / (hashlib.sha256(str(folder).encode()).hexdigest()[:32] + ".json")
    try:
        known = json.loads(record.read_text()) if record.is_file() else {}
    except (OSError, ValueError):
        known = {}
    out, fresh = [], {}
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = str(f.relative_to(folder))
        st = f.stat()
        ident = [st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]
        entry = known.get(rel)
        digest = entry[1] if entry and entry[0] == ident else _file_digest(f)
        fresh[rel] = [ident, digest]
        out.append((rel, digest))
    if fresh != known:
        _write_record(record, fresh)
    return out


def _path_digest(path: Path) -> str:
    """sha256 over a folder's files (relative path and digest of each), or a file's own digest."""
    if path.is_file():
        return _file_digest(path, remember=True)
    h = hashlib.sha256()
    for rel, digest in _dir_file_digests(path):
        h.update(rel.encode())
        h.update(digest.encode())
    return h.hexdigest()


def _path_fingerprint(value: Path) -> Any:
    if value.is_file():
        out = {"file": value.name, "sha256": _path_digest(value)}
    elif value.is_dir():
        out = {"dir": value.name, "sha256": _path_digest(value)}
    else:
        return {"missing_path": str(value)}
    for name, extra in cache_key_inputs(value).items():  # e.g. a recording's side folder
        out[name] = _path_digest(extra)
    return out


def content_fingerprint(value: Any) -> Any:
    """A JSON-able, content-based stand-in for a task input."""
    if isinstance(value, Manifest):
        return {"manifest": value.table, "hash": value.content_hash}
    if isinstance(value, Path):
        return _path_fingerprint(value)
    if isinstance(value, dict):
        return {str(k): content_fingerprint(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [content_fingerprint(v) for v in value]
    if is_dataclass(value) and not isinstance(value, type):
        return {type(value).__name__: content_fingerprint(asdict(value))}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(
        f"cannot build a content cache key from {type(value).__name__}; pass files as pathlib.Path, "
        "results of other tasks as Manifest, and everything else as plain JSON-able values"
    )


# --- the opened take, shared by the stages of a run ----------------------------------------------

#: opened takes a process keeps (the stages of one take run one after another; a folder's takes too)
OPENED_TAKES_KEPT = 4
_OPENED: "OrderedDict[tuple, Any]" = OrderedDict()
_OPENED_LOCK = threading.Lock()


def opened_take(take_dir: str | os.PathLike) -> Any:
    """The take at ``take_dir`` (demoforge.lib.takes.open_take), opened once per process while its content
    is unchanged: a flow opens it (its first check of the take) and every stage it runs gets that take
    instead of opening it again (listing the frames and reading each depth file's header, opening the
    video or salvaging a truncated one, loading a recording's index and side folder).

    Keyed by the path and the take's content fingerprint, the stage cache's own view of the take
    (remembered digests: an unchanged take is only stat'ed; a recording's side folder and annotations.json
    included), so a take changed on disk, annotated say, is opened again. Each call returns its own copy
    of the frame index: what one stage's decoding flags on a frame (an unreadable file) is not seen by
    the next, which gets the take as it was opened. The stages' parameter stays the path: a ``Path`` is
    keyed by content, while an opened take can be neither hashed for the cache nor sent to a Dask worker.
    """
    key = (str(take_dir), str(Path(take_dir).absolute()),
           json.dumps(_path_fingerprint(Path(take_dir)), sort_keys=True))
    with _OPENED_LOCK:
        take = _OPENED.get(key)
        if take is not None:
            _OPENED.move_to_end(key)
    if take is None:
        take = open_take(take_dir)
        with _OPENED_LOCK:
            _OPENED[key] = take
            while len(_OPENED) > OPENED_TAKES_KEPT:
                _OPENED.popitem(last=False)
    return replace(take, frames=[replace(f) for f in take.frames], notes=list(take.notes), meta=dict(take.meta))


def forget_opened_takes() -> None:
    """Drop the takes this process keeps open (as a new process starts)."""
    with _OPENED_LOCK:
        _OPENED.clear()


@dataclass
class ContentHashPolicy(CachePolicy):
    """Cache key = sha256(stage salt, content fingerprints of all inputs except ``ignore``)."""

    salt: str = ""
    ignore: tuple[str, ...] = ()  # inputs that cannot change the result (worker counts, progress bars)
    optional: tuple[str, ...] = ()  # inputs left out of the key while they are None (added later)

    def compute_key(
        self,
        task_ctx: TaskRunContext,
        inputs: dict[str, Any],
        flow_parameters: dict[str, Any],
        **kwargs: Any,
    ) -> str:
        payload = json.dumps(
            {"salt": self.salt,
             "inputs": content_fingerprint({k: v for k, v in (inputs or {}).items()
                                            if k not in self.ignore and not (k in self.optional and v is None)})},
            sort_keys=True,
            separators=(",", ":"),
        )
        return hashlib.sha256(payload.encode()).hexdigest()


# Inputs no stage's result can depend on, left out of every key: a take ingested with a progress bar
# (the main job) and again without one (the side-by-side ingest) is one cache entry, not two writes.
PRESENTATION_ONLY = ("show_progress",)


def stage_task(*, name: str, version: str, key_ignore: tuple[str, ...] = (), key_optional: tuple[str, ...] = (),
               **task_options: Any) -> Callable:
    """Decorate a stage function as a Prefect task with demoforge's cache policy.

    ``version`` is the code-version salt: bump it when the stage's logic changes so old cache
    entries stop matching. ``key_ignore`` names inputs left out of the cache key because they cannot
    change the result (how many worker processes; ``PRESENTATION_ONLY`` inputs are left out of every key). ``key_optional``
    names inputs left out of the key while their value is None: a parameter added to a stage later
    (e.g. a table ``variant``) keeps the keys, and so the cached results, of every call without it.
    """

    def decorate(fn: Callable) -> Any:
        ignore = tuple(dict.fromkeys((*key_ignore, *PRESENTATION_ONLY)))
        return task(
            fn,
            name=name,
            cache_policy=ContentHashPolicy(salt=f"{name}@{version}{LAYOUT}", ignore=ignore,
                                           optional=tuple(key_optional)),
            persist_result=True,
            **task_options,
        )

    return decorate


def run_stage(stage: Any, warehouse: str | os.PathLike, /, **kwargs: Any) -> Any:
    """Call a stage task with its results kept under ``warehouse``; recompute if the output is gone.

    A cache hit whose manifest names files that were deleted or changed is not trusted: the task
    runs again with ``refresh_cache=True``.
    """
    return run_stages(stage, warehouse, [kwargs])[0]


def run_stages(stage: Any, warehouse: str | os.PathLike, calls: list[dict[str, Any]]) -> list[Any]:
    """Call a stage task once per keyword dict, like :func:`run_stage`.

    Under the default task runner the calls run one after the other in this process. Inside a flow
    whose task runner is Dask they are all submitted at once, so they run in parallel on the
    cluster's workers, and the results come back in the order of ``calls``.
    """
    storage = Path(warehouse).resolve() / PREFECT_DIR / "results"
    configured = stage.with_options(result_storage=storage)
    distributed = in_distributed_flow()

    def start(task_obj: Any, kw: dict[str, Any]) -> Any:  # a future on Dask, the result otherwise
        return task_obj.submit(**kw) if distributed else task_obj(**kw)

    def finish(started: Any) -> Any:
        return started.result() if distributed else started

    results = [finish(s) for s in [start(configured, kw) for kw in calls]]
    refresh = configured.with_options(refresh_cache=True)
    redo = {i: start(refresh, calls[i]) for i, r in enumerate(results) if not _intact(r)}
    return [finish(redo[i]) if i in redo else r for i, r in enumerate(results)]


def in_distributed_flow() -> bool:
    """True inside a flow run whose task runner is Dask (prefect-dask): tasks must be submitted to
    run on its workers; a direct call would run in this process."""
    from prefect.context import FlowRunContext

    ctx = FlowRunContext.get()
    runner = getattr(ctx, "task_runner", None) if ctx is not None else None
    return runner is not None and type(runner).__name__ == "DaskTaskRunner"


def _intact(result: Any) -> bool:
    if isinstance(result, Manifest):
        return result.is_intact()
    if isinstance(result, (list, tuple)):
        return all(_intact(r) for r in result)
    if isinstance(result, dict):
        return all(_intact(r) for r in result.values())
    return True


# --- user errors in Prefect's logs ---------------------------------------------------------------

# Prefect logs every failed task and flow run with its traceback ("Task run failed with exception",
# "Encountered exception during execution"), once per enclosing flow. For a user error (demoforge.lib.errors)
# the message is the whole story: these records keep one line, the run is still marked Failed with
# the message as its state message. Crashes keep their tracebacks. `demoforge --debug` turns this off.
_RUN_LOGGERS = ("prefect.flow_runs", "prefect.task_runs")
USER_ERROR_MARK = "demoforge_user_error"


class UserErrorLogFilter(logging.Filter):
    """Drop the traceback of a user error from Prefect's run logs and put its message on one line."""

    # The starts of recent user errors' messages: the task engine's "Finished in state Failed(...)"
    # record that follows the exception's carries only the text, no exception to classify.
    _recent: list[str] = []

    def filter(self, record: logging.LogRecord) -> bool:
        if Reporting.show_tracebacks:
            return True
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None and is_user_error(exc):
            text = one_line(exc)
            record.msg, record.args = f"{type(exc).__name__}: {text}", None
            record.exc_info, record.exc_text = None, None
            setattr(record, USER_ERROR_MARK, True)
            self._recent[:] = [text[:120], *self._recent[:7]]
        elif exc is None and isinstance(record.msg, str) and record.msg.startswith("Finished in state Failed"):
            if any(t in record.getMessage() for t in self._recent):
                setattr(record, USER_ERROR_MARK, True)
        return True


class DropUserErrorLines(logging.Filter):
    """For the console while the CLI runs: it prints the user error itself, as its one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        return Reporting.show_tracebacks or not getattr(record, USER_ERROR_MARK, False)


class WarningsAsOneLine(logging.Filter):
    """For the console while the CLI runs: a stage's or flow's warning is the command's own
    ``warning: [stage: ]message`` line, printed once (the command's summary may repeat it: see
    ``demoforge.cli.root.warn``), instead of Prefect's timestamped ``WARNING | Task run ...`` line
    beside it. The record still reaches Prefect's API log."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno != logging.WARNING or not record.name.startswith(_RUN_LOGGERS):
            return True
        stage = getattr(record, "task_name", None)
        line = f"warning: {stage + ': ' if stage else ''}{one_line(record.getMessage(), 2000)}"
        if Reporting.first_time(line):
            from tqdm import tqdm

            tqdm.write(line, file=sys.stderr)  # above a progress bar, if one is drawn
        return False


def quiet_user_errors() -> None:
    """Install :class:`UserErrorLogFilter` on Prefect's run loggers (idempotent); when the CLI reports
    user errors itself (``demoforge.lib.errors.Reporting.cli_reports``), also keep those lines off the
    console, and print warnings as one line each (:class:`WarningsAsOneLine`)."""
    for name in _RUN_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, UserErrorLogFilter) for f in logger.filters):
            logger.addFilter(UserErrorLogFilter())
    if Reporting.cli_reports:
        from prefect.logging.handlers import PrefectConsoleHandler

        for handler in logging.getLogger().handlers + logging.getLogger("prefect").handlers:
            if not isinstance(handler, PrefectConsoleHandler):
                continue
            for kind in (DropUserErrorLines, WarningsAsOneLine):
                if not any(isinstance(f, kind) for f in handler.filters):
                    handler.addFilter(kind())


quiet_user_errors()
