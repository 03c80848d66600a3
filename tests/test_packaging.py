"""The installed console environment imports demoforge's own packages, wherever it runs from."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_lib_is_demoforges_package_outside_the_checkout(tmp_path):
    # llama-cpp-python leaves a bare site-packages/lib/ folder; it must not shadow lib/__init__.py
    code = "import lib, flows, schemas, tasks; print(lib.__file__); print(lib.SHARED_DATA)"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lib_file, shared = out.stdout.split()
    assert Path(lib_file) == ROOT / "lib" / "__init__.py"
    assert Path(shared) == ROOT.parent / "shared" / "data"
