"""Prefect tasks: thin adapters that read tables, call lib/, write tables.

Prefect reads its settings from the environment when it is imported; the defaults below are set
here, before any task module imports prefect, and a user's own environment always wins.
"""

import os

_PREFECT_DEFAULTS = {
    # On a loaded 2-core machine the ephemeral API server can take well over the default 20 s.
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "180",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "PREFECT_LOGGING_LEVEL": "WARNING",
}
for _key, _value in _PREFECT_DEFAULTS.items():
    os.environ.setdefault(_key, _value)
