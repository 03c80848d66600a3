"""`demoforge` commands of the hamer area (registered on flows.cli.app when imported)."""

from __future__ import annotations

from flows.cli import app, current_warehouse, fail  # noqa: F401
