"""Every environment variable demoforge reads, in one table, and one frozen object that holds them.

Convention: every name starts with ``DEMOFORGE_``. Two families are read under their own
ecosystems' names because users already set them for other tools: ``OPENAI_BASE_URL`` /
``OPENAI_API_KEY`` (OpenAI-compatible servers) and ``PREFECT_*`` / ``MUJOCO_GL`` (read by those
libraries themselves). The options of ``demoforge evaluate`` and friends are also environment
variables (``DEMOFORGE_TRIALS=10 make evaluate``): the CLI declares them, this table lists them.

Before this release some names had no prefix (``TAKES``, ``SEED``, ``LLM_MODEL``, ...).
:func:`adopt_old_names` still reads them for one release, copying each to its new name and printing
a one-line deprecation warning; the new name wins when both are set.

    settings = read_settings()          # a snapshot of the environment, read once per call
    settings.warehouse, settings.task_runner, settings.gguf_path, ...
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, MutableMapping

from demoforge.lib.errors import UserError

__all__ = ["PREFIX", "VARIABLES", "OTHER_VARIABLES", "RENAMED", "LIBRARY_DEFAULTS", "Settings", "read_settings",
           "adopt_old_names", "apply_library_defaults", "variables_table"]

PREFIX = "DEMOFORGE_"

#: name -> what it sets. The CLI options' variables are declared by the CLI with these names.
VARIABLES: dict[str, str] = {
    # where things are
    "DEMOFORGE_WAREHOUSE": "warehouse folder (default: the checkout's warehouse/; ./warehouse for an installed package)",
    "DEMOFORGE_DIGEST_CACHE": "where file and folder digests and recordings' frame indexes are remembered (default: $XDG_CACHE_HOME/demoforge/digests)",
    "DEMOFORGE_GGUF_PATH": "the local LLM's GGUF file (default: the embedded Gemma 3 270M in the venv)",
    "DEMOFORGE_HAND_LANDMARKER": "MediaPipe's hand_landmarker.task (default: the one set-up fetched into the venv)",
    "DEMOFORGE_ARCTIC_ROOT": "an ARCTIC download for evaluate-keypoints --dataset arctic",
    # how things run
    "DEMOFORGE_TASK_RUNNER": "threads (default) or dask",
    "DEMOFORGE_DASK_ADDRESS": "scheduler of an existing Dask cluster",
    "DEMOFORGE_DASK_WORKERS": "worker processes of a local Dask cluster (default 2)",
    "DEMOFORGE_DEBUG": "full tracebacks instead of one-line errors",
    "DEMOFORGE_NATIVE_LOGS": "1: MediaPipe's C++ warnings go to stderr (default: kept out of the terminal)",
    "DEMOFORGE_DETECTORS": "hand detectors `evaluate` ingests every take with",
    "DEMOFORGE_ROBOTS": "robots `evaluate` executes every task's sample with (grippers, aloha, aloha+2f140)",
    # the LLM
    "DEMOFORGE_LLM_BACKEND": "local (embedded Gemma 3 270M) or openai",
    "DEMOFORGE_LLM_MODEL": "model name of the openai backend",
    "DEMOFORGE_LLM_NUMBER_FORMAT": "thesis (metres, Appendix A) or compact (integers in mm and hundredths)",
    "DEMOFORGE_LLM_STRUCTURED": "1/0: grammar / JSON-schema constrained answers (default: on for local, off for openai)",
    "DEMOFORGE_LLM_TASKS": "tasks of the prompting evaluation in `evaluate`",
    "DEMOFORGE_LLM_THREADS": "threads of the local model (default: every core; 1 where several processes share the cores, e.g. the test workers)",
    # `demoforge evaluate`'s sizes
    "DEMOFORGE_TAKES": "synthetic takes per task and mirror flag",
    "DEMOFORGE_SEED": "first seed of the synthetic takes",
    "DEMOFORGE_MIRROR": "synthetic takes: both, no or yes (mirrored)",
    "DEMOFORGE_EPISODES": "episodes per task database",
    "DEMOFORGE_SIM_EPISODES": "episodes per task executed in MuJoCo",
    "DEMOFORGE_STABILITY_EPISODES": "episodes executed again on shifted scenes",
    "DEMOFORGE_STABILITY_REPEATS": "executions per episode of the stability check",
    "DEMOFORGE_TRIALS": "query scenes per LLM strategy",
    "DEMOFORGE_GRID_SCENES": "query scenes of the LLM-free baselines and the policy",
    "DEMOFORGE_VARIATION_TRIALS": "scenes per task and variation kind (Table 4)",
    "DEMOFORGE_POLICY_EPOCHS": "training epochs of the learned policy",
    "DEMOFORGE_POLICY_TRIALS": "scenes per kind the learned policy is judged on",
    "DEMOFORGE_SCALING_SCENES": "held-out scenes of `make evaluate`'s small data-scaling table (0 skips it)",
}

#: Other ecosystems' names demoforge reads, because users already set them for other tools.
OTHER_VARIABLES: dict[str, str] = {
    "OPENAI_BASE_URL": "the OpenAI-compatible server of the openai LLM backend",
    "OPENAI_API_KEY": "its key (never written to a file, a log or a repr)",
    "XDG_CACHE_HOME": "the user's cache folder (where the digest cache goes unless DEMOFORGE_DIGEST_CACHE is set)",
}

#: Other libraries' variables demoforge sets when the user has not: Prefect reads its settings when it
#: is imported, so ``demoforge/__init__.py`` applies them before any module can import it.
LIBRARY_DEFAULTS: dict[str, str] = {
    # a local tool on an offline machine sends nothing: the temporary (and any local) Prefect server
    # without its telemetry service (whose SQLite writes also failed with "database is locked" when
    # several commands shared ~/.prefect), and Prefect's client without usage events
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DO_NOT_TRACK": "1",
    # on a loaded 2-core machine the temporary API server can take well over the default 20 s
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "180",
    # demoforge prints its own progress and warnings (one line each); Prefect's INFO lines are noise
    "PREFECT_LOGGING_LEVEL": "WARNING",
    # MuJoCo picks its OpenGL backend when it is imported; a headless machine needs EGL (PyOpenGL follows it)
    "MUJOCO_GL": "egl",
}

#: the names of the previous release, read for one more release
RENAMED: dict[str, str] = {
    old: PREFIX + old for old in (
        "TAKES", "SEED", "MIRROR", "EPISODES", "SIM_EPISODES", "STABILITY_EPISODES", "STABILITY_REPEATS",
        "TRIALS", "GRID_SCENES", "LLM_TASKS", "LLM_BACKEND", "LLM_MODEL", "VARIATION_TRIALS",
        "POLICY_EPOCHS", "POLICY_TRIALS", "ARCTIC_ROOT")
}


def _warn(message: str) -> None:
    print(message, file=sys.stderr)


def adopt_old_names(environ: MutableMapping[str, str] | None = None,
                    warn: Callable[[str], None] = _warn) -> list[str]:
    """Copy each old, unprefixed variable that is set to its new name (unless the new one is set),
    with one warning line per name; returns the old names found."""
    env = os.environ if environ is None else environ
    found = []
    for old, new in RENAMED.items():
        if old not in env:
            continue
        found.append(old)
        if new in env:
            warn(f"warning: {old} is ignored because {new} is set; {old} is a deprecated name, unset it")
        else:
            env[new] = env[old]
            warn(f"warning: {old} is deprecated and will stop working in the next release; set {new} instead")
    return found


def apply_library_defaults(environ: MutableMapping[str, str] | None = None) -> None:
    """Set each of :data:`LIBRARY_DEFAULTS` the environment does not set already (the user's value wins)."""
    env = os.environ if environ is None else environ
    for name, value in LIBRARY_DEFAULTS.items():
        env.setdefault(name, value)
    env.setdefault("PYOPENGL_PLATFORM", env["MUJOCO_GL"])


def _positive_int(env: Mapping[str, str], name: str) -> int | None:
    raw = (env.get(name) or "").strip()
    if not raw:
        return None
    if not raw.isdigit() or int(raw) < 1:
        raise UserError(f"{name}={raw!r}: give a whole number of at least 1, or unset it")
    return int(raw)


def _path(env: Mapping[str, str], name: str) -> Path | None:
    raw = env.get(name)
    return Path(raw).expanduser() if raw else None


@dataclass(frozen=True)
class Settings:
    """The environment as demoforge reads it (None: not set, the reader's default applies)."""

    warehouse: Path | None = None
    digest_cache: Path | None = None
    gguf_path: Path | None = None
    hand_landmarker: Path | None = None
    arctic_root: Path | None = None
    task_runner: str = "threads"
    dask_address: str | None = None
    dask_workers: str = "2"
    native_logs: bool = False
    llm_backend: str | None = None
    llm_model: str | None = None
    openai_base_url: str | None = None
    openai_api_key: str | None = None
    cache_home: Path | None = None
    llm_threads: int | None = None

    def __repr__(self) -> str:  # never print a key
        key = "set" if self.openai_api_key else None
        fields = {k: v for k, v in self.__dict__.items() if k != "openai_api_key"}
        return f"Settings({', '.join(f'{k}={v!r}' for k, v in fields.items())}, openai_api_key={key!r})"

    def cache_inputs(self) -> dict[str, str | None]:
        """The settings that change what `evaluate` computes (part of its run-cache key)."""
        return {"arctic_root": str(self.arctic_root) if self.arctic_root else None,
                "llm_backend": self.llm_backend, "llm_model": self.llm_model,
                "openai_base_url": self.openai_base_url, "task_runner": self.task_runner}


def digest_cache_dir() -> Path:
    """Where file digests and recordings' frame indexes are remembered across processes
    ($DEMOFORGE_DIGEST_CACHE, else $XDG_CACHE_HOME/demoforge/digests or ~/.cache/demoforge/digests)."""
    settings = read_settings()
    if settings.digest_cache:
        return settings.digest_cache
    return (settings.cache_home or Path.home() / ".cache") / "demoforge" / "digests"


def read_settings(environ: Mapping[str, str] | None = None) -> Settings:
    """A snapshot of the environment (``os.environ`` unless given)."""
    env = os.environ if environ is None else environ
    return Settings(
        warehouse=_path(env, "DEMOFORGE_WAREHOUSE"),
        digest_cache=_path(env, "DEMOFORGE_DIGEST_CACHE"),
        gguf_path=_path(env, "DEMOFORGE_GGUF_PATH"),
        hand_landmarker=_path(env, "DEMOFORGE_HAND_LANDMARKER"),
        arctic_root=_path(env, "DEMOFORGE_ARCTIC_ROOT"),
        task_runner=(env.get("DEMOFORGE_TASK_RUNNER") or "threads").strip().lower() or "threads",
        dask_address=env.get("DEMOFORGE_DASK_ADDRESS") or None,
        dask_workers=env.get("DEMOFORGE_DASK_WORKERS", "2"),
        native_logs=env.get("DEMOFORGE_NATIVE_LOGS", "").strip() not in ("", "0"),
        llm_backend=env.get("DEMOFORGE_LLM_BACKEND") or None,
        llm_model=env.get("DEMOFORGE_LLM_MODEL") or None,
        openai_base_url=env.get("OPENAI_BASE_URL") or None,
        openai_api_key=env.get("OPENAI_API_KEY") or None,
        cache_home=_path(env, "XDG_CACHE_HOME"),
        llm_threads=_positive_int(env, "DEMOFORGE_LLM_THREADS"),
    )


def variables_table() -> str:
    """The Markdown table of every environment variable demoforge reads or sets (docs/settings.md)."""
    lines = ["| variable | what it sets |", "|---|---|"]
    lines += [f"| `{name}` | {doc} |" for name, doc in VARIABLES.items()]
    lines += [f"| `{name}` | {doc} |" for name, doc in OTHER_VARIABLES.items()]
    lines += [f"| `{name}` | set to `{value}` unless you set it (another library's setting) |"
              for name, value in LIBRARY_DEFAULTS.items()]
    lines.append("| `PYOPENGL_PLATFORM` | set to `MUJOCO_GL`'s value unless you set it |")
    return "\n".join(lines) + "\n"
