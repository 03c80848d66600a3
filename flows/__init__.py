"""Prefect flows composing the stages; the CLI and the deployments call these."""

import demoforge.tasks  # noqa: F401  (Prefect environment defaults before prefect is imported)
