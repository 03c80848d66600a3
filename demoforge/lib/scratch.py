"""Temporary folders that outlive the call that makes them but not the process."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

__all__ = ["folder_removed_at_exit"]


def folder_removed_at_exit(prefix: str) -> Path:
    """A new temporary folder, removed with its content when this process ends: for files read later in
    the same process (a salvaged video stream, a benchmark's scratch tables) that must not pile up in the
    temporary directory run after run."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, folder, True)
    return folder
