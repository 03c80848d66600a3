"""Screenshot of the `demoforge annotate` page for the README (docs/annotate.png).

    python scripts/annotate_screenshot.py TAKE [--warehouse WH] [--out docs/annotate.png]

Serves TAKE as `demoforge annotate` does, opens it in headless Chromium (tests/support/cdp.py), selects the
first keypoint and saves a PNG. Give a take that was ingested into WH so the timeline has curves.
"""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("take", type=Path)
    ap.add_argument("--warehouse", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "annotate.png")
    ap.add_argument("--frame", type=int, default=0, help="frame shown")
    args = ap.parse_args()

    from demoforge.runtime.annotate import AnnotationSession, server_url, start_server
    from tests.support.cdp import Browser

    session = AnnotationSession(args.take, args.warehouse)
    server = start_server(session, port=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    profile = Path("/tmp") / f"demoforge-shot-{id(session)}"
    browser = Browser.start(profile, width=1500, height=1040)
    try:
        browser.goto(server_url(server))
        browser.wait_for("!!document.body && document.body.dataset.ready === '1'")
        browser.click_element("#kp-row-5")
        if args.frame:
            browser.eval(f"goto({args.frame})")
        browser.eval("new Promise(r => setTimeout(r, 300))")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        browser.screenshot(args.out)
    finally:
        browser.close()
        server.shutdown()
    print(args.out)


if __name__ == "__main__":
    main()
