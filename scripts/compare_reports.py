"""Compare two reports/ folders (two `make evaluate` runs, e.g. before and after a refactoring) table by table:
every report CSV value for value with its timing columns left out, and REPORT.md's section titles.

    .venv/bin/python scripts/compare_reports.py BEFORE/reports AFTER/reports
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np
import pandas as pd

# columns that measure time on the machine that ran the job (the robots' time_scale is a result, not a timing)
TIMING = re.compile(r"(wall|_s$|_ms$|_ms_|seconds|latency|duration|frames_per_s)", re.I)


def compare_csv(before: Path, after: Path) -> tuple[str, str]:
    """(verdict, detail) of one report table."""
    a, b = pd.read_csv(before), pd.read_csv(after)
    if before.name.startswith("report_benchmarks"):
        return "timings, not compared", f"{len(a)} / {len(b)} rows"
    if list(a.columns) != list(b.columns):
        return "columns differ", str(sorted(set(a.columns) ^ set(b.columns)))
    if len(a) != len(b):
        return "row count differs", f"{len(a)} vs {len(b)}"
    skipped = [c for c in a.columns if TIMING.search(c)]
    differ = []
    for c in a.columns:
        if c in skipped:
            continue
        x, y = a[c], b[c]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            same = np.isclose(x.to_numpy(float), y.to_numpy(float), rtol=1e-9, atol=1e-12, equal_nan=True)
        else:
            same = (x.fillna("<NA>").astype(str) == y.fillna("<NA>").astype(str)).to_numpy()
        if not same.all():
            differ.append(f"{c} ({int((~same).sum())} rows)")
    verdict = "equal" if not differ else "DIFFERS: " + ", ".join(differ)
    return verdict, f"{len(a)} rows; timing columns left out: {', '.join(skipped) or '-'}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    args = ap.parse_args()
    names = sorted({p.name for p in args.before.glob("*.csv")} | {p.name for p in args.after.glob("*.csv")})
    for name in names:
        a, b = args.before / name, args.after / name
        if not (a.exists() and b.exists()):
            print(f"{name} | only in {'after' if b.exists() else 'before'}")
            continue
        print(" | ".join((name, *compare_csv(a, b))))
    titles = [[line for line in (d / "REPORT.md").read_text().splitlines() if line.startswith("## ")]
              for d in (args.before, args.after)]
    same = "the same titles in the same order" if titles[0] == titles[1] else f"differ: {set(titles[0]) ^ set(titles[1])}"
    print(f"REPORT.md sections: {len(titles[0])} before, {len(titles[1])} after; {same}")


if __name__ == "__main__":
    main()
