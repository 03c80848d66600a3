"""demoforge: one RGB-D video of a two-handed task in, thousands of dual-arm robot episodes out.

The design card's folders are this package's subpackages: ``demoforge.lib`` (pure domain code, by
pipeline stage), ``demoforge.schemas`` (table contracts, the warehouse, the catalog),
``demoforge.tasks`` (cached Prefect tasks) and ``demoforge.flows`` (Prefect flows). The application
shell lives here: ``demoforge.cli`` (the command line), ``demoforge.runtime`` (task runners, the
whole-run cache, Prefect artifacts) and ``demoforge.bench`` (every benchmark). The four folders live
in this one (plain subpackages: every import resolves statically, in a checkout and in the wheel); the
repository's top-level ``lib``, ``tasks``, ``flows`` and ``schemas`` are symbolic links to them.
"""

# Other libraries' settings (Prefect: no telemetry, quiet logs; MuJoCo: EGL) before any module imports them; the
# user's environment wins (demoforge.lib.settings.LIBRARY_DEFAULTS).
from demoforge.lib.settings import apply_library_defaults as _apply_library_defaults  # noqa: E402

_apply_library_defaults()
