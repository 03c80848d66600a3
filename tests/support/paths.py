"""Where things are, for the tests: the checkout they run in and the folders they read (one place, so a
test file can move without its paths changing)."""

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]  # the checkout: demoforge/, tests/, scripts/, docs/
TESTS = REPO_ROOT / "tests"
SUPPORT = TESTS / "support"
GOLDEN = SUPPORT / "golden"  # pinned outputs the tests compare with
HOLD_POINTS = SUPPORT / "hold_points"  # its sitecustomize parks a `demoforge` process (flows/test_evaluate.py)
# ../shared/data beside the checkout, as the checkout lays it out (demoforge.lib.SHARED_DATA may point elsewhere)
CHECKOUT_SHARED_DATA = REPO_ROOT.parent / "shared" / "data"
