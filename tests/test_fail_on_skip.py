"""`DEMOFORGE_FAIL_ON_SKIP=1` (.ci/run) fails a run that skipped a test, whether or not ../shared/data
is present: pytest runs of a file whose one test skips, with the suite's own hooks (tests/conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from tests.support.paths import REPO_ROOT

ROOT = REPO_ROOT


def test_a_skip_fails_the_run_under_fail_on_skip_with_or_without_the_shared_data(tmp_path):
    (tmp_path / "test_skips.py").write_text(
        "import pytest\n\ndef test_skipped():\n    pytest.skip('something truly absent')\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "DEMOFORGE_FAIL"))}

    def run(fail_on_skip: str, shared_data_here: bool) -> subprocess.CompletedProcess:
        # the suite's hooks, with ../shared/data where it is or pointed at a folder that does not exist
        (tmp_path / "conftest.py").write_text(
            "import demoforge.lib\n"
            + ("" if shared_data_here else "demoforge.lib.SHARED_DATA = demoforge.lib.SHARED_DATA / 'gone'\n")
            + "from tests.conftest import pytest_sessionfinish, pytest_terminal_summary  # noqa: F401\n")
        return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                               str(tmp_path / "test_skips.py")], cwd=tmp_path, capture_output=True, text=True,
                              env={**env, "PYTHONPATH": str(ROOT), "DEMOFORGE_FAIL_ON_SKIP": fail_on_skip}, timeout=120)

    # without ../shared/data (where it was the case that let skips pass; with it, skips always failed)
    r = run("1", False)
    assert r.returncode == 1 and "DEMOFORGE_FAIL_ON_SKIP: 1 test(s) skipped" in r.stdout, r.stdout[-2000:]
    assert "shared/data/gone is absent" in r.stdout
