"""Run-level cache of the main job: `demoforge evaluate` with nothing changed returns in about a second.

Every stage is cached by Prefect on the content of its inputs, but confirming that for ~100 stages
costs a Prefect API server and a minute of cache lookups. Before that, this module checks the whole
run at once: the same parameters, the same code (content of every .py under lib/, tasks/, flows/,
schemas/ and the dependency pins), the same external inputs (real photos, ARCTIC root, LLM settings)
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

PROJECT_ROOT = Path(__file__).resolve().parents[1]
CODE_DIRS = ("lib", "tasks", "flows", "schemas")
RUNS_DIR = "_runs"
# rebuilt by every query / owned by Prefect's per-stage cache: not outputs of the run
IGNORED = {"catalog.duckdb", "catalog.duckdb.wal", "_prefect", RUNS_DIR}


def code_fingerprint(root: Path = PROJECT_ROOT) -> str:
    h = hashlib.sha256()
    files = [p for d in CODE_DIRS for p in (root / d).rglob("*.py")]
    files += sorted((root / "requirements").glob("*.txt")) + [root / "pyproject.toml"]
    for p in sorted(f for f in files if f.is_file()):
        h.update(str(p.relative_to(root)).encode())
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
