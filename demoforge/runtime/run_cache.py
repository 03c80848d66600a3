"""Run-level cache of the main job: `demoforge evaluate` with nothing changed returns in about a second.

Every stage is cached by Prefect on the content of its inputs, but confirming that for ~100 stages
costs a Prefect API server and a minute of cache lookups. Before that, this module checks the whole
run at once: the same parameters, the same code (content of every .py of the demoforge package: lib/,
tasks/, flows/, schemas/ and demoforge/ itself, wherever they are installed, and in a checkout the
dependency pins), the same external inputs (real photos, ARCTIC root, LLM settings)
and a warehouse whose files are exactly as the last complete run left them (size and modification
time of every file). Any difference, including a table file deleted by hand, means a normal run, in
which Prefect's per-stage cache recomputes only what changed.

No Prefect import here: the fast path must not pay for it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from demoforge.lib.settings import read_settings
from demoforge.schemas.core import file_sha256

CODE_PACKAGES = ("demoforge", "demoforge.lib", "demoforge.tasks", "demoforge.flows", "demoforge.schemas")
RUNS_DIR = "_runs"
# rebuilt by every query / owned by Prefect's per-stage cache: not outputs of the run
IGNORED = {"catalog.duckdb", "catalog.duckdb.wal", "_prefect", RUNS_DIR}


def code_dirs() -> dict[str, Path]:
    """{package: its folder}: the code of a run. Found through the imported packages, since the
    folders are not nested the same way in a checkout (setup.py maps demoforge.lib to lib/) and in an
    installed wheel."""
    import importlib

    return {name: Path(importlib.import_module(name).__file__).resolve().parent for name in CODE_PACKAGES}


def code_fingerprint(dirs: dict[str, Path] | None = None) -> str:
    """Hash of every .py file of ``dirs`` (default :func:`code_dirs`; a package's subpackages that are
    packages of their own are hashed once, under their own name) and, in a checkout, the dependency pins."""
    dirs = code_dirs() if dirs is None else dirs
    own = set(dirs.values())
    h = hashlib.sha256()
    n = 0
    for name, root in sorted(dirs.items()):
        for p in sorted(root.rglob("*.py")):
            # a folder inside root that is a package of its own (demoforge/lib): hashed under its name
            if any(root / sub in own for sub in p.relative_to(root).parents if sub != Path(".")):
                continue
            h.update(f"{name}/{p.relative_to(root)}".encode())
            h.update(file_sha256(p).encode())
            n += 1
    if n == 0:
        raise RuntimeError(f"no source files found under {sorted(map(str, own))}: the run cache cannot see the code")
    checkout = dirs.get("demoforge", Path("/nonexistent")).parent
    for p in sorted((checkout / "requirements").glob("*.txt")) + [checkout / "pyproject.toml"]:
        if p.is_file():
            h.update(p.name.encode())
            h.update(file_sha256(p).encode())
    return h.hexdigest()


def tree_state(root: Path, ignored: set[str] = frozenset()) -> dict[str, list[int]]:
    """{relative path: [size, mtime_ns]} of every file under root (cheap: stat only)."""
    out: dict[str, list[int]] = {}
    if not root.exists():
        return out
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in ignored)
        for name in filenames:
            if name in ignored:
                continue
            p = Path(dirpath) / name
            st = p.stat()
            out[str(p.relative_to(root))] = [st.st_size, st.st_mtime_ns]
    return out


def run_key(params: dict[str, Any], external: dict[str, str | None]) -> str:
    inputs = {name: tree_state(Path(path)) if path and Path(path).exists() else None
              for name, path in sorted(external.items())}
    payload = {"params": params, "code": code_fingerprint(), "inputs": inputs,
               "env": read_settings().cache_inputs()}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def _record_path(warehouse: Path, key: str) -> Path:
    return warehouse / RUNS_DIR / f"evaluate-{key[:32]}.json"


def lookup(warehouse: str | Path, key: str) -> Path | None:
    """The report of a complete run with this key whose outputs are untouched, else None."""
    warehouse = Path(warehouse)
    record = _record_path(warehouse, key)
    try:
        saved = json.loads(record.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    report = Path(saved.get("report", ""))
    if not report.is_file() or tree_state(report.parent) != saved.get("reports"):
        return None
    if tree_state(warehouse, IGNORED) != saved.get("warehouse"):
        return None
    return report


def remember(warehouse: str | Path, key: str, report: str | Path) -> None:
    """Record a complete run (atomically: a crash leaves no half record)."""
    warehouse, report = Path(warehouse), Path(report)
    record = _record_path(warehouse, key)
    record.parent.mkdir(parents=True, exist_ok=True)
    tmp = record.with_name(f".{record.name}.tmp")
    tmp.write_text(json.dumps({"report": str(report), "reports": tree_state(report.parent),
                               "warehouse": tree_state(warehouse, IGNORED)}))
    tmp.replace(record)
