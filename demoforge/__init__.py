"""demoforge: one RGB-D video of a two-handed task in, thousands of dual-arm robot episodes out.

The design card's folders are this package's subpackages: ``demoforge.lib`` (pure domain code, by
pipeline stage), ``demoforge.schemas`` (table contracts, the warehouse, the catalog),
``demoforge.tasks`` (cached Prefect tasks) and ``demoforge.flows`` (Prefect flows). The application
shell lives here: ``demoforge.cli`` (the command line), ``demoforge.runtime`` (task runners, the
whole-run cache, Prefect artifacts) and ``demoforge.bench`` (every benchmark). Installed, the
subpackages sit inside this folder (the wheel maps them, see setup.py); in a checkout they stay at
the top of the repository, found through this package's search path.
"""

from pathlib import Path as _Path

# A checkout: lib/, tasks/, flows/, schemas/ beside this folder are demoforge.lib, ... (an installed
# wheel has them inside this folder, and no pyproject.toml beside it).
_checkout = _Path(__file__).resolve().parent.parent
if (_checkout / "pyproject.toml").is_file() and (_checkout / "lib" / "__init__.py").is_file():
    __path__.append(str(_checkout))  # noqa: F821 (a package's __path__)

# Other libraries' settings (Prefect: no telemetry, quiet logs; MuJoCo: EGL) before any module imports them; the
# user's environment wins (demoforge.lib.settings.LIBRARY_DEFAULTS).
from demoforge.lib.settings import apply_library_defaults as _apply_library_defaults  # noqa: E402

_apply_library_defaults()
