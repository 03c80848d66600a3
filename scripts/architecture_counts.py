"""Count what tests/test_architecture.py checks, on this checkout or another (e.g. an older commit's
worktree), for before/after comparisons: modules, import edges at module level and inside functions,
module and room loops, private names imported across files and rooms, functions over 120 lines.

    .venv/bin/python scripts/architecture_counts.py [--root CHECKOUT]
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.import_graph import cycles, find_modules, imported, room  # noqa: E402


def counts(root: Path) -> dict:
    modules = find_modules(root)
    edges: dict[str, set[str]] = {}
    at_top = in_functions = 0
    private_files, private_rooms, long_functions = [], [], []
    for m, path in modules.items():
        tree = ast.parse(path.read_text())
        top_lines = {n.lineno for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))}
        found = imported(m, path, modules)
        edges[m] = {t for t, _, _ in found}
        pairs = {(t, line in top_lines) for t, _, line in found}
        at_top += sum(1 for _, top in pairs if top)
        in_functions += sum(1 for _, top in pairs if not top)
        for t, what, _ in found:
            if what and what.startswith("_") and not what.startswith("__"):
                private_files.append((m, what))
                if room(t) != room(m):
                    private_rooms.append(f"{m} <- {t}.{what}")
        long_functions += [f"{m}.{n.name} ({n.end_lineno - n.lineno + 1})" for n in ast.walk(tree)
                           if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > 120]
    room_edges: dict[str, set[str]] = {}
    for m, ts in edges.items():
        room_edges.setdefault(room(m), set()).update(room(t) for t in ts if room(t) != room(m))
    return {"modules": len(modules), "module-level import edges": at_top, "import edges inside functions": in_functions,
            "module loops": cycles(edges), "room loops": cycles(room_edges),
            "private names imported across files": len(private_files),
            "private names imported across rooms": private_rooms, "functions over 120 lines": long_functions}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1], help="the checkout to count")
    for key, value in counts(ap.parse_args().root.resolve()).items():
        if isinstance(value, list):
            print(f"{key}: {len(value)}")
            for item in value:
                print(f"    {item}")
        else:
            print(f"{key}: {value}")


if __name__ == "__main__":
    main()
