"""Prefect tasks: thin adapters that read tables, call lib/, write tables.

Prefect reads its settings from the environment when it is imported; demoforge's defaults for them
(``demoforge.lib.settings.LIBRARY_DEFAULTS``: no telemetry, quiet logs, a patient server start) are set
by ``demoforge/__init__.py``, before any module of the package can import prefect; a user's own
environment always wins.
"""
