"""Pure domain code of demoforge: geometry, hands, tasks, augmentation, retrieval, metrics.

No Prefect and no warehouse layout knowledge lives here.
"""

import os
from pathlib import Path

# ../shared/data beside the checkout: the real third-party data (hand photos, an RGB-D frame).
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# MuJoCo picks its OpenGL backend at import time; headless machines need EGL (Mesa software).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
